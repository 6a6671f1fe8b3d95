"""Speed measurements (never timed tests): ``triplesumo bench env`` is :mod:`triplesumo.benchmarks.env`."""
