"""Sensor register tables and drivers."""
