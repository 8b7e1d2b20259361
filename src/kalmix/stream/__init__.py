"""The parts of :mod:`kalmix.streaming`, its public front: settings (:mod:`.config`), column detection
(:mod:`.columns`), length and time units (:mod:`.units`), times as seconds (:mod:`.times`), the gap rule
(:mod:`.gaps`), track ids (:mod:`.ids`), the track state store (:mod:`.store`), and the
:class:`~kalmix.streaming.TrackPredictor` (:mod:`.predictor`), put together from its bank and engine runs
(:mod:`.bank_runs`), its tracks' clocks (:mod:`.clocks`), rows as they arrive (:mod:`.row_steps`), tables
(:mod:`.table_steps`) and its state file (:mod:`.state_file`). Import from :mod:`kalmix.streaming` (or
:mod:`kalmix`)."""
