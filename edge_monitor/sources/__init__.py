"""Sources: every way bytes become per-joint samples, behind one sample interface.

A *source* turns what a controller sends (CAN frames live or from a log, another controller's DBC frames,
CiA 402 drive PDOs, trace tables, the simulator's cycle arrays) into labelled per-joint samples: an
:class:`~edge_monitor.sources.samples.IngestBlock` of :class:`~edge_monitor.sources.samples.CycleRun` s,
each holding per joint its controller ticks, motor speed [rad/s], motor torque [fraction of T_ref] and
segment code, plus its load estimate, σl and motor temperature [°C] per status frame, under one cycle
number (:mod:`~edge_monitor.sources.samples` states the units). ``edge_monitor.pipeline`` takes it from
there: ``Agent.update_ingested(block)``, or, for a source of frames, ``Agent(config, source=…)`` with an
object of the shape of :class:`~edge_monitor.sources.samples.SampleSource`. Sources import nothing of the
pipeline (tests/test_architecture.py).

The sources:

* our native frames: :mod:`frame_source` (live buses as frame blocks), :mod:`log_source` (log files,
  resynchronising after damage; BLF read by :mod:`blf_blocks`, text logs' lines by :mod:`text_logs`),
  :mod:`ingest` (decode, CRC, E2E, counters, per-joint runs; which status frames may change the cycle:
  :mod:`cycle_numbering`);
* other controllers, through a mapping file (docs/CONNECTING.md): :mod:`dbc_source` (any DBC),
  :mod:`cia402_source` (CiA 402 drives), :mod:`trace_source` (CSV/Parquet trace tables), each giving
  :class:`~edge_monitor.sources.samples.DecodedSamples`; :mod:`sample_stream` labels them with cycles from
  the controller's marks, a trigger or the motion (:mod:`cycle_labels`); :mod:`foreign_source` is the
  source the agent takes instead of ``ingest`` (:func:`~edge_monitor.sources.foreign_source.open_source`
  builds it from a mapping); :mod:`signal_check` the commissioning report (``check-mapping``);
  :mod:`trace_export` the other way round, a recording as a trace table (``export-trace``);
* the simulator's cycle-level mode: :mod:`cycle_arrays` (driven by ``edge_monitor.offline.fast_path``).

Adding a source. A controller with frames described by a DBC or an EDS needs no code: write a mapping file.
For a new kind of input, write one module here that turns its input into ``DecodedSamples`` (times [s], speed
and torque in the agent's units, the marks it has) with a class of the shape of the ``FrameDecoder`` protocol
in :mod:`foreign_source` (``decode(ids, data, dlc, timestamps)``, ``c``, ``describe()``), add its mapping kind
to ``protocol.signal_mapping.KINDS`` and let :func:`~edge_monitor.sources.foreign_source.decoder_for` return
it for that kind; ``SampleStream`` and ``ForeignSource`` then label cycles and count drops as for the others.
An input that already knows its cycles may produce ``IngestBlock`` s itself, as :mod:`cycle_arrays` does.
Count every sample you drop with a reason; never raise on bad data. Tests to copy:
tests/test_foreign_sources.py (the same friction curves as our native frames for the same simulated robot),
tests/test_hostile_traces.py (damaged and hostile input: a one-line message or a counted drop),
tests/test_fast_path.py (a source that equals the frame path).
"""
