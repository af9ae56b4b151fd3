"""The ``glint`` command: the composition of worker's, the server's and the benchmarks' commands
(cli.py). It is the only package that imports all three; worker imports neither of the others."""
