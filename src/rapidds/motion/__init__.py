"""Robot motion: the scheduler-facing interface, the trajectory diffusion policy, steering."""
