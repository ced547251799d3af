"""``python -m hlip_jax``: the ``hlip-sweep`` command line."""

from hlip_jax.presentation.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
