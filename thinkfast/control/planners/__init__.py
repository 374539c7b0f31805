"""The executor's planners: the interface (base), one module per planner and the registry that
names them (registry). Importing this package imports no planner: the registry loads each one
when an executor is built with it."""
