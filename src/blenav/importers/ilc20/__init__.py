"""Import Indoor Location Competition 2.0 recordings (and the 2021 Kaggle challenge layout) into dataset format v1.

Source: XYZ10, Inc., Indoor Location Competition 2.0 sample data, GitHub
location-competition/indoor-location-competition-20 (MIT licence; see ``SOURCE.txt`` beside the raw copy).
The 2021 "Indoor Location & Navigation" challenge (204 buildings) uses the same path-file format.

Input (``src``)
---------------
* a floor folder ``<site>/<floor>/{floor_info.json, geojson_map.json, floor_image.png, path_data_files/*.txt}``,
  a site folder holding floor folders, or any folder above them (repository layout);
* the challenge layout ``train/<site>/<floor>/*.txt`` with ``metadata/<site>/<floor>/{floor_info.json,
  geojson_map.json}`` (``src`` may be the folder holding both, or ``train`` itself when ``metadata`` is its
  sibling);
* a ``.tar.gz`` / ``.tgz`` / ``.tar`` or ``.zip`` of either, read member by member (tar: one streaming pass)
  without unpacking to disk. Each member's declared size is checked before it is read (at most
  ``BLENAV_MAX_ARCHIVE_MEMBER_MB``, default 256 MiB; the largest path file of the sample is 4.1 MB), and so is
  the archive's expansion (at most ``BLENAV_MAX_ARCHIVE_RATIO``, default 200, times its size plus 64 MiB; the
  sample's archives expand 5.1-5.6 times): a member over either is refused naming it. Links and special
  members are not read; the report counts them. Nothing is written under a member's name.

``floors`` (``--floors SITE/FLOOR,...``) keeps only those floors; a name that matches no floor is an error
listing the floors found. Site and floor names are the folder names (``site1``, ``F1``).

What is written
---------------
* One building per site (folder name, e.g. ``site1``; ``name`` = the path files' ``SiteName``), one floor per
  floor folder, floor id = the folder name (``B1``, ``F1``, a string). Floor ``z`` = level x
  ``FLOOR_HEIGHT_M`` (5 m, **assumed**; level from the name: ``F<k>``/``L<k>``/``<k>F`` -> k - 1,
  ``B<k>`` -> -k, else the GeoJSON outline's ``floor_num`` - 1, else 0).
* **Frames.** Every floor keeps the upstream floor frame, the frame of its waypoints: x east, y north, metres,
  origin at the south-west corner of the bounding box of the floor outline. The outline's longitude/latitude
  bounding box maps linearly onto ``[0, width] x [0, height]`` (``floor_info.json`` ``map_info``), the
  alignment described in SOURCE.txt. Floors of one site therefore have slightly different origins (format v1
  wants one origin per building): building.yaml ``floor_frames`` gives each floor's bounding box in
  longitude/latitude and the shift (m) of its origin from the first floor's, for consumers that move between
  floors. The alignment is checked per floor against the waypoints (below).
* **Occupancy grid** at ``RESOLUTION_M`` = 0.1 m/px covering ``[0, width] x [0, height]``, origin (0, 0):
  a pixel is FREE (walkable) when its centre lies inside the floor outline (holes excluded) and outside every
  unit polygon; inside a unit it is UNKNOWN (grey, 205): shops are entered through doors the plan does not
  draw, and surveyors did walk into them (one B1 walk has 3 of its 5 waypoints inside units), so a unit is
  "not known to be free", not a wall; outside the outline it is OCCUPIED. Rasterised with PIL's polygon fill
  (exact to about one pixel at edges); holes of unit polygons are not cut out (none in the sample data).
  ``floor_image.png`` is not used.
* **Rooms**: every unit (shop) polygon becomes a ``rooms.geojson`` feature in floor metres, ``id`` = the
  unit's GeoJSON id (else ``<floor>-unit<i>``), ``name`` = its name. An invalid polygon is repaired with
  shapely's ``make_valid`` (counted in the report); empty ones are dropped (counted).
* **Alignment check** (per floor, in the report and in building.yaml ``alignment``): the share of all
  waypoints of the floor inside the outline, on FREE cells of the grid, and inside a unit; plus the ratio of
  ``floor_info`` width/height to the outline's geodesic size (1.0 = the same scale). A floor with under half
  of its waypoints on FREE cells would fail the validator's ``groundtruth-in-obstacles`` rule.
* ``anchors.csv``: one ``kind: ble`` row per iBeacon transmitter heard, **position unknown** (x, y, z empty:
  the data gives none; ``blenav-map`` estimates them). ``anchor_id`` = ``UUID:major:minor:MAC`` (upper case):
  in this data the iBeacon triple alone does not identify a beacon: over the three floors 327 MACs advertise
  ``9195B3AD-A9D0-4500-85FF-9FB0F65A5201:0:0`` (the mall's beacons, almost all rows from MACs E0:78:A3:...),
  and another triple is advertised by 113 MACs (devices with rotating addresses). ``beacon_id="triple"``
  writes ``UUID:major:minor`` instead. ``floor`` = the floor where it was heard most often (a guess: heard
  on several floors, see ``floors_heard``); ``tx_power_dbm`` = the median advertised measured power (RSSI at
  1 m) when it lies in (-150, 0) dBm, else empty. Extra columns: ``uuid, major, minor, mac, n_rows,
  floors_heard``.
* One session per path file, id ``<site>_<floor>_<path id>``: ``carrier: pedestrian``, ``device_model`` =
  ``<Brand> <Model>`` from the header (``unknown`` when absent), ``receiver_brand``, ``android``,
  ``groundtruth_kind: waypoints``, ``orientation_frame``, the upstream ``site_id``/``floor_id``/``path_id``,
  ``start_unix_ms``, ``sensor_time_offset_s``, ``records`` (rows per record type read).

  - ``imu.csv``: TYPE_ACCELEROMETER (m/s^2 incl. gravity) and TYPE_GYROSCOPE (rad/s), Android device frame
    (the format's frame; no conversion). TYPE_GYROSCOPE is the phone's bias-corrected stream: session.yaml
    ``gyro_calibrated: true``. **Time alignment**: when both streams have the same timestamps (all
    walks of the sample: the app logs them together) rows are paired; otherwise the gyroscope is linearly
    interpolated at the accelerometer times and accelerometer samples outside the gyroscope's time span are
    dropped (counted).
  - ``mag.csv``: TYPE_MAGNETIC_FIELD (calibrated, microtesla). The ``*_UNCALIBRATED`` streams are not imported.
  - ``orientation.csv`` (format extension): TYPE_ROTATION_VECTOR as a unit quaternion ``qw, qx, qy, qz``
    (``qw = sqrt(1 - x^2 - y^2 - z^2)``, Android's ``getQuaternionFromVector``) rotating device-frame vectors
    into Android's East-North-Up frame, whose y axis points to *magnetic* north (session.yaml
    ``orientation_frame: enu-magnetic``); the floor frame's y is geographic north of the map, so they differ
    by the magnetic declination (about -5 deg at the ILC mall) plus the map's own error.
  - ``rssi.csv``: TYPE_BEACON rows, ``t`` = the row's time, ``rssi`` dBm. Readings not in (-150, 0) dBm are
    dropped and counted.
  - ``wifi.csv`` (format extension): TYPE_WIFI rows: ``t`` = the scan's row time, ``bssid`` (lower case),
    ``rssi_dbm``, ``freq_mhz``; extra ``ssid`` and ``t_seen`` (the AP's ``last_seen`` time on the session
    clock, s; it can precede the scan by tens of seconds, and the session's start: a cached reading).
    Every row of a delivery is written, stale or not: a delivery (one every ~2 s on the sample walks) holds the
    access points of the scan just made, heard 0.5-2 s before ``t``, and cached ones heard seconds to minutes
    before (on site1 F1 40 % of the rows were heard over 5 s before their delivery). Readers decide:
    fingerprinting drops rows heard over 5 s before ``t`` (default) or, opted in (issue 29), before the
    delivery's newest ``t_seen`` and places the scan at the median ``t_seen`` of the rest
    (:mod:`blenav.features.fingerprints`). ``TYPE_BEACON`` rows carry
    their own reception time (the last field equals the row time on every sample row), so ``rssi.csv`` is
    already at the times the advertisements were heard.
    Readings not in (-150, 0) dBm are dropped and counted; a frequency outside 2000..8000 MHz is left empty.
  - ``groundtruth.csv``: the surveyed TYPE_WAYPOINT rows only (x, y in floor metres; z = floor z +
    ``PHONE_HEIGHT_M`` 1.2 m, assumed; orientation empty; extra ``raw_line``). Nothing is interpolated:
    consumers that need denser labels interpolate between waypoints and say so. A walk with fewer than two
    waypoints is written ``labelled: false`` without groundtruth.csv (its waypoint, if any, in session.yaml
    ``waypoints``).

Time
----
Every row carries a Unix time in ms. The session clock is ``t = (unix_ms - t0) / 1000`` s with ``t0`` the
header's ``startTime`` (the first row's time when the header lacks it, or the earliest row when a row precedes
it). Rows of each stream are sorted by time (stable): waypoints, for one, are logged out of file order.
**Sensor vs system time**: sensor rows (accelerometer, gyroscope, magnetometer, rotation vector) carry the
SensorEvent time aligned to Unix time by the recording app, other rows the system time. In the 365 walks
of the sample the sensor rows start 106..189 ms after ``startTime`` and end at most 11 ms after ``endTime``,
so no offset is applied. When the sensor times of a walk lie more than ``SENSOR_CLOCK_TOL_S`` (10 s) outside
the walk's system-time span (an app that did not align the SensorEvent clock: boot time), the sensor streams
are shifted so that their first sample falls at the walk's start, and the shift is written as
``sensor_time_offset_s`` (0.0 otherwise) and counted in the report.

Bad input
---------
A line that does not parse (too few or too many tab-separated fields for its record type, a time that is
not an integer, a value that is not a finite number, a blank line inside the file, bytes that are not
UTF-8) or a file that does not end with a newline (its last line may be cut) raises
:class:`~blenav.errors.ImportError_` naming the file (``archive:member`` inside an archive) and the
1-based line. Record types the format does not document are counted per type and reported, never fatal;
documented types that are not imported (uncalibrated streams, TYPE_BLUE/BLU4/DIST1/DIST2, accuracy changes)
are counted as ignored. A walk without an ``endTime`` header line (possibly cut exactly at a line end) is
imported and counted. Output goes to a temporary folder beside ``out`` that is renamed to ``out`` only when
everything parsed, so a parse error leaves nothing behind; the validator then checks ``out`` (a dataset it
refuses stays there for inspection, and the import raises its errors).
"""

from .run import import_ilc20

__all__ = ["import_ilc20"]
