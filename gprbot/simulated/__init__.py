"""The simulated robot: the simulated world's devices and sensors through the robot's own stages (no hardware)."""
