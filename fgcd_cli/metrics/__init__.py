"""Measurements: FDF/AFD between images, change-detection scores."""
