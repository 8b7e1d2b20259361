"""The parts of :mod:`kalmix.streaming`, its public front: settings (:mod:`.config`), column detection
(:mod:`.columns`), length and time units (:mod:`.units`), the gap rule (:mod:`.gaps`), track ids (:mod:`.ids`) and
the track state store (:mod:`.store`). Import from :mod:`kalmix.streaming` (or :mod:`kalmix`)."""
