# ruff: noqa: E501  (the YAML text is written as shipped: one source line is long)
"""The physiological flow presets the generated small-artery trees carry (config/vessels/small_artery_4gen.yaml,
synthetic_tree_3d.yaml): appended as written, after the generated network, by tools/make_branching_network.py and
tools/make_synthetic_tree_3d.py.  docs/vessels.md, "Physiological flow presets"."""

#: The YAML text appended (a blank line, the commented ``flow_presets:`` block).
FLOW_PRESETS_YAML = """
# Physiological flow presets (physics.flow.preset: <name>; docs/vessels.md "Physiological flow presets").  Not in the
# geometry's or the field's hash: the shipped field is unchanged.
flow_presets:
  - name: brachial_levenson_1981
    # J. A. Levenson, P. A. Peronneau, A. Simon, M. E. Safar, "Pulsed Doppler: determination of diameter, blood
    # flow velocity, and volumic flow of brachial artery in man", Cardiovasc. Res. 15(3):164-170, 1981: 22 healthy
    # men, brachial diameter 4.40 +/- 0.10 mm, mean blood velocity 9.15 +/- 1.01 cm/s, flow 85 +/- 10 ml/min.
    # Ours: that mean velocity taken over unscaled to this 3 mm trunk (no source for a 3 mm artery's flow at
    # hand; the flow is then 39 ml/min); V_f = 2 x 0.0915 = 0.183 m/s (Poiseuille); the pulsatility is Table
    # III's a_f (the source gives no peak) and the heart rate Table III's 1 Hz; no outlet shares: the network's
    # own split (cfd.outlet_split, Murray's law) stays.
    source: "Levenson et al., Cardiovasc. Res. 15(3):164-170, 1981 (brachial artery, mean velocity); pulsatility, heart rate: Table III (ours)"
    mean_velocity_m_per_s: 0.0915
    pulsatility: 1.15
    heart_rate_per_min: 60.0
"""
