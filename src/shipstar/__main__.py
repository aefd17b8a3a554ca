"""``python -m shipstar`` runs the command line."""

if __name__ == "__main__":          # not when a worker process (multiprocessing spawn) imports it
    from shipstar.cli import _entry

    _entry()
