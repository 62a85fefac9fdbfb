"""The historian: every agent's records in one database (SQLite or PostgreSQL), stored exactly once,
thinned by retention, and answered over Zenoh (``edge/history/**``) and the command line
(docs/HISTORIAN.md).

Modules: ``identity`` (what a record is and its exactly-once key), ``migrations`` and ``database`` (the
schema and connections on both databases), ``writes`` (storing a batch and the fleet tables), ``writer``
(the batching thread that outlives database outages), ``query_spec``, ``queries``, ``fleet``, ``gaps``
(the questions and their answers), ``retention``, ``jsonl_import``, ``zenoh_answers`` (the queryable),
``client`` (asking it), ``service`` (the running historian), ``db_url``, ``times``.
"""
