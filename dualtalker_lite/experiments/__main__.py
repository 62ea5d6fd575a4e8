"""``python -m dualtalker_lite.experiments``: the experiment runner's command line (:func:`.command.main`)."""
if __name__ == "__main__":
    from ..console import run_main
    from .command import main

    run_main(main)  # user errors as one line, Ctrl-C stops the workers and exits 130
