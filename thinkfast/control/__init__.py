"""Control: intake, the executor (throw episodes) with its throw gate, planners (planners/: the
interface, one module per planner, the registry), segment timeline and hedge stage, segments
and wrist, the safety supervisor and the clock-free control core (detections and EGM feedback
in, setpoints out, time passed in) that the daemon and the lockstep simulator both drive; the
runtime configuration."""
