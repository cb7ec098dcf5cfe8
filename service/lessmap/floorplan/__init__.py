"""Floor plans: occupancy grids, their ground-truth rooms, robots simulated on them, room maps."""
