"""What the evaluation reads: data sets, simulated runs, segmentations as frame labels."""
