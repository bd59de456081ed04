"""``python -m h4bench``: the command line (the same as the ``h4bench`` script)."""

from h4bench.scenarios.cli import app

if __name__ == "__main__":
    app()
