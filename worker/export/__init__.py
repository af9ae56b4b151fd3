"""Standard exports of a Glint scene: glTF 2.0 binary, MaterialX (OpenPBR) and Mitsuba 3.

Every format goes through one material approximation (``approx``): the glTF 2.0
metallic-roughness BRDF fitted to the Glint material, with its errors reported.
"""
