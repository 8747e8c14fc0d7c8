"""The robot the daemon runs: the simulated robot, the runtime's tasks, the survey runner, the shell handler."""
