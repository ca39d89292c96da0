"""Inputs of the learned models, computed without PyTorch: the layer between :mod:`blenav.data` and both
:mod:`blenav.learn` (training) and :mod:`blenav.runtime` (running exports, as a phone app would).

- :mod:`blenav.features.scale`: the thesis RSSI scale u = rssi_dBm + 100 and the networks' u / 100;
- :mod:`blenav.features.windows`: the beacon order of a model, beacon subsets (``spread_beacons``), the
  RSSI transform and the windows S (B beacons x H steps) of a session, the split of sessions by phone;
- :mod:`blenav.features.mapgrid`: a floor's free mask on the map prior network's grid (resampling, the
  pixel lookup, the DMT cache key, padding to the U-Net's size multiple).

Needs numpy and pandas only (it reads :mod:`blenav.data` sessions and floors it is given); imports nothing of
torch, lightning, hydra, the simulator, the filters or the runtime, so everything above may use it.
"""
