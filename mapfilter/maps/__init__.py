"""Maps: the floor plan (wall mask, map files), map preparation from plans, the wall walk."""
