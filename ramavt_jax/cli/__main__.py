"""`python -m ramavt_jax.cli ...` = `ramavt ...`."""

from ramavt_jax.cli.main import main

main()
