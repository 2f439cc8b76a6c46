"""The ``audio2pose`` command line (graph runner, demo, synthesis, benchmark, model building)."""
