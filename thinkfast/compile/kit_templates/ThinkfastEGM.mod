MODULE ThinkfastEGM
    !=====================================================================================
${header}
    !
    ! thinkfast controller kit: joint-mode EGM for thinkfast-run (the EGM sensor).
    !
    ! RobotWare 6 syntax (IRC5, option 689-1 Externally Guided Motion). RobotWare 7
    ! (OmniCore) differences are noted where relevant; README.md beside this file lists
    ! them. A COMMISSIONING STARTING POINT, not a validated program: load it in a
    ! RobotStudio virtual controller first (docs/EGM_CONTROLLER.md, "Commissioning").
    !
    ! The values below are the ones docs/EGM_CONTROLLER.md recommends, with its reasons;
    ! tests/test_controller_kit.py fails when this file, that page, the UDP device
    ! (sys_cfg_udpuc.cfg) or the daemon's defaults disagree. Change them together.
    !
    ! Use: the program moves home once (operator watching), then waits. Setting the
    ! persistent tf_start_request to TRUE (FlexPendant Program Data, or RWS) starts one
    ! EGM session; tf_stop_request ends it deliberately. A session lost to a silent
    ! daemon stops the program: restart thinkfast-run, press Start, request again.
    !=====================================================================================

    !------------------------------------------------------------------ names
    ! ExtConfigName of EGMSetupUC: the External Motion Interface Data instance
    ! (Configuration > Motion; moc_ext_motion_thinkfast.cfg beside this file).
    CONST string EGM_EXT_CONFIG := "thinkfast";
    ! UCdevice of EGMSetupUC: the UDP unicast device (Configuration > Communication >
    ! Transmission Protocol; sys_cfg_udpuc.cfg beside this file, same Name).
    CONST string EGM_UC_DEVICE := "THINKFAST";

    !------------------------------------------------------------------ EGM arguments
    ! EGMSetupUC \CommTimeout [s]: a daemon silent this long ends the session
    ! (ERR_UDPUC_COMM below). Longer than the daemon's safety.resync_after (0.02 s).
    ! NOT VERIFIED that the controller accepts a fractional value: check in RobotStudio.
    CONST num EGM_COMM_TIMEOUT := 0.1; ! [s]
    ! EGMActJoint \SampleRate [ms], multiple of 4: one EgmRobot per safety.dt (0.004 s).
    CONST num EGM_SAMPLE_RATE := 4; ! [ms]
    ! EGMActJoint \LpFilter [Hz]: bandwidth of the controller's reference filter.
    CONST num EGM_LP_FILTER := 20; ! [Hz]
    ! EGMActJoint \MaxSpeedDeviation [deg/s]: joint speed cap of EGM, every joint; the
    ! fastest positioning max_velocity of robot.toml (${v_fastest} deg/s, ${v_fastest_joints}),
    ! rounded up: a lower cap makes the arm lag the tree's plan. For the first tests lower
    ! max_velocity and generate the kit again.
    CONST num EGM_MAX_SPEED_DEV := ${max_speed_dev}; ! [deg/s]
    ! EGMActJoint \J1..\J6 [deg]: convergence window per joint (only matters with
    ! \CondTime).
    CONST egm_minmax EGM_CONV := [-0.1, 0.1]; ! [deg]
    ! EGMRunJoint \CondTime [s]: the arm rests at home (converged) between throws, so
    ! this must outlast a working session. The largest accepted value is NOT VERIFIED.
    CONST num EGM_COND_TIME := 3600; ! [s]
    ! EGMRunJoint \RampInTime [s]: the daemon starts from the measured joints.
    CONST num EGM_RAMP_IN_TIME := 0.1; ! [s]
    ! EGMRunJoint and EGMStop \RampOutTime [s]: duration of the stop (v_max / a_max of
    ! ${stop_joints} is ${stop_time} s).
    CONST num EGM_RAMP_OUT_TIME := 0.3; ! [s]
    ! EGMRunJoint \PosCorrGain [0..1]: 1 because the daemon sends position AND speedRef;
    ! 0 would let a frozen speed reference run until the timeout.
    CONST num EGM_POS_CORR_GAIN := 1; ! [0..1]
    ! Stop mode of EGMRunJoint and EGMStop: HOLD stops the arm where it is.
    ! EGM_STOP_RAMP_DOWN would drive it back to where the session began: a move
    ! thinkfast neither planned nor checked for collisions. Never use it here.
    CONST egmstopmode EGM_STOP_MODE := EGM_STOP_HOLD;

    !------------------------------------------------------------------ home
    ! thinkfast's home (${home_source}, radians) in degrees.
    CONST jointtarget TF_HOME := [[${home_deg}], [9E9, 9E9, 9E9, 9E9, 9E9, 9E9]];
    ! COMMISSIONING: the shield is mounted on the flange. Define it as tooldata with its
    ! measured load (LoadIdentify) and pass it to MoveAbsJ and EGMActJoint (\Tool:=);
    ! tool0 tells the controller there is no payload.

    !------------------------------------------------------------------ requests
    ! Set TRUE (FlexPendant Program Data, or RWS) to start one EGM session. Cleared by
    ! the program; a request made while a session runs is dropped.
    ! (A digital input works as well: replace WaitUntil by WaitDI.)
    PERS bool tf_start_request := FALSE;
    ! Set TRUE to end the running session with EGMStop (HOLD, EGM_RAMP_OUT_TIME).
    PERS bool tf_stop_request := FALSE;
    ! Where the program is, for RWS clients (thinkfast-cell): "homing" (moving home),
    ! "waiting" (tf_start_request is cleared and will be taken), "session" (an EGM
    ! session is set up or running), "lost" (the daemon went silent; program stopped).
    ! Written by the program only; after a RAPID stop it names where the program stopped.
    PERS string tf_status := "";

    VAR egmident egm_id;
    VAR intnum tf_stop_int;

    PROC main()
        ! The one ordinary move, at low speed with an operator watching: a stop point at
        ! thinkfast's home. Every session starts from a standing arm.
        tf_status := "homing";
        MoveAbsJ TF_HOME, v100, fine, tool0;
        tf_stop_request := FALSE;
        IDelete tf_stop_int;
        CONNECT tf_stop_int WITH tf_stop_trap;
        ! IPers: interrupt on every change of the persistent (also back to FALSE).
        IPers tf_stop_request, tf_stop_int;
        WHILE TRUE DO
            tf_start_request := FALSE;
            ! After the clear: a request made once "waiting" shows is never lost.
            tf_status := "waiting";
            TPWrite "thinkfast: waiting for tf_start_request";
            WaitUntil tf_start_request;
            tf_start_request := FALSE;
            tf_session;
        ENDWHILE
    ENDPROC

    ! One EGM session: set up, activate, run until EGMStop, \CondTime or a lost daemon.
    PROC tf_session()
        tf_status := "session";
        WaitRob \InPos;
        EGMReset egm_id;
        EGMGetId egm_id;
        EGMSetupUC ROB_1, egm_id, EGM_EXT_CONFIG, EGM_UC_DEVICE \Joint \CommTimeout:=EGM_COMM_TIMEOUT;
        ! RW7 (7.20, one public report): \PosCorrGain is not accepted by EGMActJoint;
        ! it is not passed here (it belongs to EGMRunJoint).
        EGMActJoint egm_id
            \J1:=EGM_CONV \J2:=EGM_CONV \J3:=EGM_CONV
            \J4:=EGM_CONV \J5:=EGM_CONV \J6:=EGM_CONV
            \LpFilter:=EGM_LP_FILTER
            \SampleRate:=EGM_SAMPLE_RATE
            \MaxSpeedDeviation:=EGM_MAX_SPEED_DEV;
        TPWrite "thinkfast: EGM session running";
        EGMRunJoint egm_id, EGM_STOP_MODE
            \J1 \J2 \J3 \J4 \J5 \J6
            \CondTime:=EGM_COND_TIME
            \RampInTime:=EGM_RAMP_IN_TIME
            \RampOutTime:=EGM_RAMP_OUT_TIME
            \PosCorrGain:=EGM_POS_CORR_GAIN;
        TPWrite "thinkfast: EGM session ended";
        EGMReset egm_id;
    ERROR
        IF ERRNO = ERR_UDPUC_COMM THEN
            ! thinkfast-run was silent for EGM_COMM_TIMEOUT: EGM has ended the session
            ! and stops the arm with EGM_STOP_MODE (HOLD) over EGM_RAMP_OUT_TIME.
            ErrWrite \W, "thinkfast-run silent", "No EGM answer within the comm timeout:"
                \RL2:="EGM session ended, arm held."
                \RL3:="Restart thinkfast-run, press Start, then"
                \RL4:="set tf_start_request.";
            TPWrite "thinkfast: EGM session lost (daemon silent), program stopped";
            EGMReset egm_id;
            tf_status := "lost";
            ! No RETRY: an operator acknowledges with Start once the daemon runs again;
            ! the program then waits for a new tf_start_request.
            Stop \NoRegain;
            RETURN;
        ENDIF
        ! Any other error: stop the program with the controller's own message.
        RAISE;
    ENDPROC

    ! Deliberate end of a session (docs/EGM_CONTROLLER.md: EGMStop from a TRAP).
    ! NOT VERIFIED that EGMStop may run in a TRAP while EGMRunJoint waits in the main
    ! routine. If the controller rejects it, use EGMRunJoint \NoWaitCond followed by
    ! WaitUntil tf_stop_request and EGMStop in tf_session, or end the session with a
    ! RAPID stop (the controller then ends EGM itself).
    TRAP tf_stop_trap
        IF tf_stop_request THEN
            tf_stop_request := FALSE;
            IF EGMGetState(egm_id) = EGM_STATE_RUNNING THEN
                EGMStop egm_id, EGM_STOP_MODE \RampOutTime:=EGM_RAMP_OUT_TIME;
            ENDIF
        ENDIF
    ENDTRAP
ENDMODULE
