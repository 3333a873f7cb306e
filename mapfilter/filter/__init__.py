"""The regularised particle filter: particle state, models, resampling, the step loop."""
