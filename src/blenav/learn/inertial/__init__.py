"""Learned inertial odometry (issue 31): data (:mod:`.data`), module and loss (:mod:`.module`), training
(:mod:`.train`), checkpoint (:mod:`.checkpoint`), ONNX export (:mod:`.export`)."""
