"""What a frame tells: ground truth from the renderer's ids, the camera sensor, and the detectors."""
