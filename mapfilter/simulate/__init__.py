"""Synthetic walks and surveys over a map, written in the ILC trace format (``walk``, ``ilc_writer``)."""
