"""``python -m planet_intersect ...``: the same command line as ``planet-intersect``."""

from .cli import main

if __name__ == "__main__":
    raise SystemExit(main())
