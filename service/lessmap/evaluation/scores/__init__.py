"""What a segmentation is scored by: information loss (Eq. 5), consistency, area graphs."""
