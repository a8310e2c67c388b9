"""`python -m mdpipe export RUN_DIR --format netcdf|zarr` (what the
binary's `mdpipe export` calls)."""

import sys

from .export import main

if __name__ == "__main__":
    args = sys.argv[1:]
    if args[:1] == ["export"]:
        args = args[1:]
    sys.exit(main(args))
