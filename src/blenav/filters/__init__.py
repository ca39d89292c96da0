"""The particle-filter engine and its components.

- :mod:`~blenav.filters.engine`: the SIR algorithm over R runs x N particles (log weights, n_eff, resampling,
  recovery, estimates);
- :mod:`~blenav.filters.resampling`: systematic, stratified, multinomial, residual, low-variance;
- :mod:`~blenav.filters.motion`: RW, DR, the IMU proposal (Ghaffari Jadidi et al. eqs. 4-7), odometry
  increment (Roy eq. 3.7), PDR;
- :mod:`~blenav.filters.measurement`: PF-PL path-loss ranges, PF-PS RSSI-domain likelihood (Patel et al.);
- :mod:`~blenav.filters.map`: map-aware initialisation and resampling (Patel et al. section V), wall
  crossing, rooms and routes derived from the occupancy grid when a building lacks them;
- :mod:`~blenav.filters.map_prior`: Roy's learned map prior (eq. 3.8) as a measurement, with per-particle
  odometry-frame heading bins and an odometry window; a non-learned reference prior;
- :mod:`~blenav.filters.attitude`: AHRS (Madgwick, Mahony, EKF from the ``ahrs`` package) after a median prefilter;
- :mod:`~blenav.filters.steps`: sensor streams -> per-step controls and observations (batch and streaming);
- :mod:`~blenav.filters.method`: what one method is (``Method``, its ``MapSpec``); :mod:`~blenav.filters.runner`: one
  method on one session for R runs; :mod:`~blenav.filters.online`: the same, sample by sample (``OnlineLocalizer``);
  :mod:`~blenav.filters.estimate`: the ``Estimate`` they and every localizer return;
- :mod:`~blenav.filters.calibration`: path-loss fit from labelled sessions (``blenav-calibrate``);
- :mod:`~blenav.filters.memory`: malloc settings that keep the filter's per-step temporaries off fresh pages.
"""

from .memory import keep_freed_memory

keep_freed_memory()  # applied once, on import of the filters (see blenav.filters.memory)
