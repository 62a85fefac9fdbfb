"""Detector evaluation by simulation (``edge-monitor evaluate``, docs/EVALUATION.md).

One concept per module: :mod:`.factors` (the factors and their coded levels), :mod:`.design` (central
composite and validation designs), :mod:`.simulate` (one design point through the simulator and the
agent), :mod:`.runner` (all points in parallel processes), :mod:`.surrogate` (second-order models),
:mod:`.scope` (SNR and scope matrices by Monte Carlo on the surrogates) and :mod:`.report` (plots,
JSON, Markdown).
"""
