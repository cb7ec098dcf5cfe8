"""LESS-mapping as published: CovGraph, CovRate, Shi–Malik bisection, the double test, submaps."""
