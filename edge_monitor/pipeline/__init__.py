"""The agent laid out as its data flow: frame sources → ingest (decode, E2E) → joint monitors
(features, detectors) → records → sinks; plus the live loop and state persistence."""
