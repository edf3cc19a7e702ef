"""Hardware and file drivers: cameras (V4L2/OpenCV, replay, simulated) and the serial strobe trigger."""
