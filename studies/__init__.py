"""The machinery of the detector studies: one small package, imported by the command-line drivers under
tools/studies/ and by the tests; not shipped (the wheel holds the product only).

* :mod:`studies.series` — per-cycle quantities of simulated robots (the fast path, detectors off), computed
  once per code version and kept in ``.cache/fleet_series/``;
* :mod:`studies.bank_replay` — the agent's own detectors over kept series (:func:`~studies.bank_replay.replay_bank`,
  the one replay every study uses), and a value in a detector's standard units;
* :mod:`studies.robots` — a fleet of simulated robots through the whole agent or only its detectors, one run
  record per robot; :mod:`studies.tally` — what a study counts of them (exposure, false alarms, detections,
  reported against observed misses);
* :mod:`studies.delivered` — the delivered false-alarm rate against the stated one, target by target, from one
  replay; :mod:`studies.budgets` — what a false-alarm budget costs in detection (the cost table);
* :mod:`studies.settings` — seeds and agent settings from a command line; :mod:`studies.statistics` — Poisson
  intervals and variance ratios.

It sits above the product in the layers (tests/test_architecture.py): it may import any of ``edge_monitor``,
``sim_controller``, ``joint_model`` and ``protocol``, nothing of the product imports it, and it reads the
product through public names only, as the drivers under tools/ do (no ``._private`` access: a test checks).
"""
