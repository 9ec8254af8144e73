"""Acquiring calibration references: cameras and illuminators behind small interfaces."""
