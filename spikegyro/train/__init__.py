"""Dataset windows, augmentation, loss and the training loop.

From Python (what ``spikegyro train`` and the demo do)::

    from spikegyro.train.presets import resolve_config
    from spikegyro.train.loop import train

    config = resolve_config("cpu", {"data": "data/demo", "out": "runs/demo"})
    result = train(config)            # result.run_dir / "best.pt", result.val["val_median_rel"]

and to evaluate a checkpoint on the fixed test windows::

    from spikegyro.models.registry import load_checkpoint
    from spikegyro.train.data import fixed_windows
    from spikegyro.train.infer import predict_windows

    model, payload = load_checkpoint("runs/demo/best.pt")
    windows = fixed_windows("data/demo", "test", payload["input"]["window_ms"])
    omega = predict_windows(model, payload, windows)      # (n, T, 3) rad/s, per millisecond

Modules: :mod:`~spikegyro.train.data` (windows and encodings), :mod:`~spikegyro.train.augment`
(flips and time inversion with exact labels), :mod:`~spikegyro.train.loss`,
:mod:`~spikegyro.train.presets` (``paper`` and ``cpu``), :mod:`~spikegyro.train.loop`,
:mod:`~spikegyro.train.distributed` (DDP under torchrun), :mod:`~spikegyro.train.infer`;
learning from real events without a gyro: :mod:`~spikegyro.train.selfsup` (the contrast loss),
:mod:`~spikegyro.train.real` (real recordings as unlabeled windows) and
:mod:`~spikegyro.train.adapt` (``spikegyro adapt``).
"""
