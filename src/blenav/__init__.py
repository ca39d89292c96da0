"""blenav: indoor localization from BLE beacons, inertial sensors and floor plans."""

__version__ = "0.1.0"
