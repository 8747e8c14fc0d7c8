"""The simulated world: scenes, the GPR forward model, robot and sensor models."""
