"""What a run shows and records: the metrics loggers, the progress bar, the console's lines, the
plots and their statistics.
"""
