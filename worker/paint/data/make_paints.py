# Writes worker/paint/data/paints.json from the transcribed Ngan et al. (2005) Lafortune fits (run from the repo root).
import json, sys
sys.path.insert(0, '.')
from worker.paint.database import build_entry
# name: (rho_d rgb, rho_s rgb, Cxy, Cz, n, category)
T = {
 "blue-metallic-paint":   ((0.0146, 0.00932, 0.0209), (0.129, 0.105, 0.16), -0.594, 0.542, 13.7, "metallic"),
 "blue-metallic-paint2":  ((0.015, 0.0189, 0.0254), (0.0939, 0.128, 0.174), -0.578, 0.577, 1520, "metallic"),
 "dark-blue-paint":       ((0.0171, 0.0175, 0.029), (0.178, 0.132, 0.0927), -0.633, 0.446, 20.4, "solid"),
 "dark-red-paint":        ((0.26, 0.0361, 0.0118), (0.223, 0.169, 0.109), -0.656, 0.372, 24.8, "solid"),
 "gold-metallic-paint":   ((0.0601, 0.0298, 0.00487), (0.475, 0.27, 0.0681), -0.596, 0.537, 12.8, "metallic"),
 "gold-metallic-paint2":  ((0.0971, 0.0591, 0.0212), (0.257, 0.165, 0.0656), -0.578, 0.577, 1220, "metallic"),
 "gold-metallic-paint3":  ((0.066, 0.0474, 0.0238), (0.233, 0.173, 0.0978), -0.583, 0.566, 27.4, "metallic"),
 "gold-paint":            ((0.173, 0.0838, 0.0202), (0.209, 0.147, 0.0657), -0.595, 0.541, 14.3, "pearl"),
 "green-metallic-paint":  ((0.015, 0.0537, 0.0428), (0.22, 0.217, 0.153), -0.591, 0.548, 76, "metallic"),
 "green-metallic-paint2": ((0.0081, 0.0195, 0.00728), (0.0499, 0.0868, 0.0385), -0.578, 0.577, 1400, "metallic"),
 "light-red-paint":       ((0.424, 0.0442, 0.0111), (0.235, 0.184, 0.128), -0.652, 0.386, 18.6, "solid"),
 "orange-paint":          ((0.419, 0.126, 0.00903), (0.191, 0.152, 0.0951), -0.652, 0.387, 16.6, "solid"),
 "pearl-paint":           ((0.2, 0.152, 0.0879), (0.242, 0.176, 0.0855), -0.598, 0.534, 10.9, "pearl"),
 "purple-paint":          ((0.284, 0.0356, 0.0242), (0.3, 0.252, 0.168), -0.584, 0.564, 346, "solid"),
 "red-metallic-paint":    ((0.0651, 0.00888, 0.0051), (0.0899, 0.0165, 0.00654), -0.577, 0.577, 3070, "metallic"),
 "silver-metallic-paint": ((0.0552, 0.05, 0.0359), (0.434, 0.363, 0.243), -0.587, 0.559, 21.4, "metallic"),
 "silver-paint":          ((0.184, 0.132, 0.0795), (0.251, 0.221, 0.156), -0.594, 0.542, 13.7, "pearl"),
 "white-paint":           ((0.321, 0.271, 0.183), (0.436, 0.325, 0.244), -0.58, 0.573, 1630, "solid"),
 "yellow-paint":          ((0.308, 0.177, 0.0217), (0.181, 0.15, 0.0956), -0.637, 0.434, 27.4, "solid"),
 "paint-black":           ((0.0178, 0.0149, 0.0103), (0.392, 0.326, 0.217), -0.579, 0.574, 1290, "solid"),
 "blue-acrylic":          ((0.0145, 0.0332, 0.064), (0.0238, 0.0164, 0.01), -0.577, 0.577, 4060, "solid"),
 "green-acrylic":         ((0.0175, 0.0648, 0.0244), (0.0327, 0.0263, 0.0158), -0.577, 0.577, 5080, "solid"),
 "white-acrylic":         ((0.313, 0.258, 0.155), (0.0581, 0.0409, 0.0264), -0.578, 0.577, 3980, "solid"),
 "acrylic-yellow":        ((0.225, 0.233, 0.0489), (0.0121, 0.00852, 0.00599), -0.577, 0.577, 7280, "solid"),
 "specular-black-phenolic":  ((0.00269, 0.00259, 0.00217), (0.0114, 0.0073, 0.00456), -0.577, 0.577, 9610, "solid"),
 "specular-white-phenolic":  ((0.285, 0.197, 0.0755), (0.5, 0.541, 0.353), -0.58, 0.573, 2420, "solid"),
 "specular-red-phenolic":    ((0.299, 0.0295, 0.00488), (0.0183, 0.0142, 0.0101), -0.577, 0.577, 3950, "solid"),
 "specular-blue-phenolic":   ((0.00446, 0.011, 0.0184), (0.0322, 0.022, 0.0135), -0.577, 0.577, 5220, "solid"),
 "specular-green-phenolic":  ((0.00697, 0.0214, 0.0128), (0.0251, 0.018, 0.0129), -0.577, 0.577, 5490, "solid"),
 "specular-yellow-phenolic": ((0.304, 0.116, 0.00863), (0.0162, 0.0108, 0.00835), -0.577, 0.577, 4770, "solid"),
}
paints = []
for name, (rd, rs, cxy, cz, n, cat) in T.items():
    e = {"name": name, "category": cat, "source": {"model": "lafortune", "rho_d": list(rd), "rho_s": list(rs),
         "Cxy": cxy, "Cz": cz, "n": n, "measured": "MERL BRDF database (Matusik et al. 2003)",
         "fit": "Ngan, Durand, Matusik 2005, Lafortune model"}}
    paints.append(build_entry(e))
doc = {"about": "30 paints and glossy coatings of the MERL BRDF database as Lafortune fits published by "
       "Ngan et al. 2005; measurements computed by worker.paint.database.build_entry (see README, PROVENANCE).",
       "paints": paints}
open('worker/paint/data/paints.json', 'w').write(json.dumps(doc, indent=1) + "\n")
for p in paints:
    m = p["measurements"]
    print(f'{p["name"]:26s} {p["category"]:8s} G={m["gloss"]:7.2f} FI={p["flop_index"]:6.2f} R15={m["aspecular"]["15"][1]:.3f} R45={m["aspecular"]["45"][1]:.3f} R110={m["aspecular"]["110"][1]:.3f}')
