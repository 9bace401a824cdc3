"""Training layer, host side: the driver (``driver.run``), its compiled program cache (``program``), checkpoints
(``checkpoint``), the run-folder layout, metrics log, lock and config check (``run_folder``), whole-or-nothing file
writes and strict JSON (``files``) and clean stops on signals (``interrupts``). The jitted trainer itself is
:mod:`ramavt_jax.train`, its config :mod:`ramavt_jax.train_config`.
"""
