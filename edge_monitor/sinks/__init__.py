"""Where records go: JSON Lines files, Zenoh (publisher, session, maintenance) and Rerun."""
