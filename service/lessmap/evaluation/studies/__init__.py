"""Studies that compare methods and parameters: the areas benchmark, sweeps, diagnosis."""
