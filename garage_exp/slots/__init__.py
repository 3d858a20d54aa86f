"""Parking slots and their marking points on the bird's-eye view: ground truth, detectors and what they share."""
