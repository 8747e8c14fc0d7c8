"""Kiwi kinematics, heading hold, limits and the survey planner (pure, no I/O)."""
