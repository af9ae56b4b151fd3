"""Static publications: turntables of final frames for the shopper viewer (turntable.py: the
cameras; keys.py: the content key of every frame's inputs; frames.py: rendering and encoding a
batch of them in a worker; manifest.py: the bundle's manifest, its one documented format)."""
