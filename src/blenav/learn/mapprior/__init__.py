"""The learned map prior (Roy, section 3.2.2): data (:mod:`.data`, its schema :mod:`.data_config`), the
LightningModule (:mod:`.module`), training (:mod:`.train`, ``task: mapprior``), checkpoint meta and loading
(:mod:`.checkpoint`) and the ONNX export in two graphs (:mod:`.export`). The Lightning run, checkpoint reading and
ONNX tracing are shared with the cross-phone localizer. Nothing is imported here: the schema loads without torch."""
