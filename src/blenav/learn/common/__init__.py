"""What the learned models' training shares: the Lightning run (:mod:`.trainer`: seeding, loggers, OUT/last.ckpt,
resuming, learning curves, the step-budget callback), the step budget and its learning-rate schedule
(:mod:`.budget`, :mod:`.schedule`), reading checkpoints safely (:mod:`.checkpoint`), tracing to ONNX
(:mod:`.onnx_export`), the training report (:mod:`.report`) and a sweep's bookkeeping (:mod:`.sweep`). It knows no
model: the model packages (:mod:`blenav.learn.crossphone`, :mod:`blenav.learn.mapprior`,
:mod:`blenav.learn.fingerprint`) import it, never the reverse. Nothing is imported here.

Today the map prior uses the run (``start_run``, ``fit``), checkpoint reading and tracing, and trains for epochs;
the step budget, its schedule, the step-budget callback, the learning-curve monitor and the report serve the
cross-phone task (and the fingerprint networks, trained through it)."""
