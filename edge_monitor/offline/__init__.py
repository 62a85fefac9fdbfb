"""Offline engineering tools: commissioning (model identification) and experiment design."""
