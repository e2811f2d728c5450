"""Scenes: cameras, images and initial points, from disk or built in."""
