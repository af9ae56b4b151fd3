"""Lighting capture from fisheye photos (cyber-worlds §IV), with automatic lens-frame removal.

manifest.py  capture manifest v1 (pydantic), photos, exposures (manifest or EXIF)
fisheye.py   the two projections, pixels ↔ directions, yaw
hdr.py       bracket alignment (MTB), response recovery (Debevec), HDR merge (C kernel + NumPy)
frame.py     lens-frame detection
stitch.py    fisheyes → equirectangular map: feathering, exposure matching, inpainting
pipeline.py  the whole path; EXR and preview encoding
job.py       the service's side: safe zip extraction, run_capture
synth.py     synthetic captures of real HDRIs with known truth
cli.py       glint capture, glint capture-synth
"""
