"""Calibrations: the camera check (Zhang) and the physical veil fit."""
