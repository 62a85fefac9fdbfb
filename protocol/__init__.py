"""Shared wire format: frame catalogue, scaling, E2E protection, DBC, links (docs/PROTOCOL.md)."""
