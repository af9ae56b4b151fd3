"""Benchmarks of Glint, outside the runtime packages: their commands (cli.py), the service over
real WebSockets (stream.py), precomputation on a Ray cluster (ray_precompute.py). The scene
files beside them (*.json) are the benchmark scenes; profile_frame.py and shade_inputs.py are
scripts run on their own."""
