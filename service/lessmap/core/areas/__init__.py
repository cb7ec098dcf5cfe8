"""Areas on top of LESS-mapping: pooled evidence, confirmed splits, recognised revisits."""
