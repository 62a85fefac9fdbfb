"""Simulated robot controller streaming motor torque and speed over CAN."""
