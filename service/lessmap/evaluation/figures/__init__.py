"""Figures (matplotlib, imported only when drawing): segmentations, buildings, area graphs."""
