"""The RSSI scales of the learned BLE localizer (Roy, section 3.1.3), shared by the simulator, training and
the runtime.

- The thesis scale u = rssi_dBm + :data:`THESIS_OFFSET_DB` (Table 3.2 of the thesis: about 30 for a beacon
  at 1 m, i.e. the -70 dBm 1 m level of our receiver model); 0 means "not heard".
- The networks read u / :data:`U_SCALE` (values in [0, about 0.7]): the statistic similarity loss weighs
  deviations by exp((S - M) / 0.1), which overflows on the raw thesis scale (see :mod:`blenav.learn.crossphone.losses`).
"""

#: thesis scale: u = rssi_dbm + THESIS_OFFSET_DB
THESIS_OFFSET_DB = 100.0
#: the networks' input scale: u / U_SCALE
U_SCALE = 100.0
