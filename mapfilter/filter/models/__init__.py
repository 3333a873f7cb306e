"""The filter's models, each one file behind the interfaces of ``interface.py``: motion (random
walk, constant velocity, PDR), measurements (a position fix, trilateration and its adaptive
form, the radio map's own likelihood, the measurement sources' models: BLE, ...), a building's
floors and barometer, and the frame a model sees a building in (``frame.py``).
A new model is a new file here; nothing in the filter's core changes."""
