"""The cross-phone localizer (TransNet + LocNet, Roy section 3.1) and its baselines: RSSI windows (:mod:`.data`, its
schema :mod:`.data_config`), losses (:mod:`.losses`), receiver augmentation (:mod:`.augment`), the LightningModule
(:mod:`.module`), training (:mod:`.train`, ``task: crossphone``), checkpoint meta and loading (:mod:`.checkpoint`),
the streaming ONNX export (:mod:`.export`) and the baselines of Roy's Table 3.5 (:mod:`.baselines`). The run, the
step budget, checkpoint reading, tracing and the training report are :mod:`blenav.learn.common`'s. Nothing is
imported here: the schema loads without torch."""
