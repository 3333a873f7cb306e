"""The IPIN competition's trials on its EvaalAPI server: the protocol's messages, estimates and
score (``protocol``), the client (``client``) and the same client over a log file (``replay``)."""
