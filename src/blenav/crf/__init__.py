"""The linear-chain CRF of Duembgen et al. (004) on a grid, solved with Viterbi (numpy + numba, no torch).

* :mod:`.grid`: 0.5 m cells over the floor's free space, sparse wall-respecting transitions (CSR);
* :mod:`.features`: RTT (eq. 6), BLE RSSI (eqs. 11-12), IMU (eqs. 13-14), visual reset (eq. 15);
* :mod:`.preprocess`: 1 s medians and the rejection rules of sec. V-A;
* :mod:`.calibration`: none / offline (static points) / online (visual fixes) calibration, sec. V-B;
* :mod:`.viterbi`: the max-product step with pruning (eq. 4), argmax (eq. 16), backtracking (sec. IV-B).

The localizer is :class:`blenav.localizers.crf.CrfLocalizer`.
"""
