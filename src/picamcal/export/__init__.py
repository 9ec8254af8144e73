"""Putting the calibration into the camera: libcamera tuning files, the legacy MMAL table, ISP emulation."""
