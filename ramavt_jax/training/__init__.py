"""Training layer, host side: the driver (``driver.run``), its compiled program cache (``program``), checkpoints
(``checkpoint``), the run-folder layout, lock and config check (``run_folder``) and clean stops on signals
(``interrupts``). The jitted trainer itself is :mod:`ramavt_jax.train`, its config :mod:`ramavt_jax.train_config`.
"""
