"""Training layer, host side: the driver (``driver.run``), the run folder opened and its checkpoints restored
(``resume``), the chunk loop with its logs, checkpoints and clean stops (``chunk_loop``), host reads of the
[seeds]-stacked state (``host_state``), its compiled program cache (``program``), checkpoints (``checkpoint``), the
run-folder layout, metrics log, lock and config check (``run_folder``), whole-or-nothing file writes and strict JSON
(``files``) and clean stops on signals (``interrupts``). The jitted trainer itself is :mod:`ramavt_jax.train`, its
config :mod:`ramavt_jax.train_config`.
"""
