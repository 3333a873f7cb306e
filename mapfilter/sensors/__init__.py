"""Sensors: log readers, WiFi scans, access points and path loss, radio maps, dead reckoning.

Nothing here knows about the filter: these modules turn files into measurements.
"""
