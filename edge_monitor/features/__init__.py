"""Per-cycle features of one joint: plateau segmentation, friction extraction, wear estimation, the
distribution-domain (KL) monitor and its disturbance-rejecting weights (docs/ALGORITHMS.md §2–§4)."""
