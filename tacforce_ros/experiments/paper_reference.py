"""The paper's published numbers (tactile-force-estimation.tex), the only typed-in figures of the
report. Errors: e_r in %, e_hat / e_track / e_tilde in N, as mean and standard deviation.
"""
from __future__ import annotations

# Table I (tab:offline-results): 5-fold leave-one-plate-out benchmark; tau = "computation time
# for a single prediction" [ms].
TABLE_I = {
    'index_tip': {     # "Curved Array"
        'M1': {'e_r': (52, 21.04), 'e_hat': (0.75, 0.34), 'tau_ms': 0.393},
        'M2': {'e_r': (54, 23.57), 'e_hat': (0.72, 0.35), 'tau_ms': 0.691},
        'M3': {'e_r': (34, 19.47), 'e_hat': (0.36, 0.23), 'tau_ms': 0.047},
        'M3-lambda': {'e_r': (33, 19.14), 'e_hat': (0.35, 0.23), 'tau_ms': 0.044},
        'M4': {'e_r': (24, 14.80), 'e_hat': (0.27, 0.18), 'tau_ms': 0.051},
        'M5': {'e_r': (23, 12.04), 'e_hat': (0.25, 0.15), 'tau_ms': 0.370},
    },
    'index_middle': {  # "Flat Array"
        'M1': {'e_r': (39, 20.13), 'e_hat': (0.37, 0.20), 'tau_ms': 0.053},
        'M2': {'e_r': (38, 19.12), 'e_hat': (0.34, 0.20), 'tau_ms': 0.082},
        'M3': {'e_r': (38, 20.84), 'e_hat': (0.31, 0.20), 'tau_ms': 0.046},
        'M3-lambda': {'e_r': (37, 20.67), 'e_hat': (0.31, 0.19), 'tau_ms': 0.040},
        'M4': {'e_r': (27, 15.79), 'e_hat': (0.23, 0.15), 'tau_ms': 0.050},
        'M5': {'e_r': (27, 14.36), 'e_hat': (0.22, 0.14), 'tau_ms': 0.230},
    },
}

# Table II (tab:online-results): index fingertip on the held-out spherical plate, 200 s online.
TABLE_II = {
    'M3-lambda': {'e_r': (25.70, 11.00), 'e_hat': (0.31, 0.14)},
    'M4': {'e_r': (20.90, 9.80), 'e_hat': (0.21, 0.10)},
}
ONLINE_SECONDS = 200.0

# Table III (tab:control-results): (1) spherical indenter, (2) foam brick, (3) softball,
# (4) abrasive sponge, (5) bleach cleanser; the open loop only on (1), only e_tilde.
TABLE_III = {
    ('spherical', 'open_loop'): {'e_tilde': (0.46, 0.15)},
    ('spherical', 'M3-lambda'): {'e_r': (20.32, 7.08), 'e_hat': (0.12, 0.08),
                                 'e_track': (0.06, 0.05), 'e_tilde': (0.12, 0.08)},
    ('spherical', 'M4'): {'e_r': (4.86, 6.86), 'e_hat': (0.04, 0.03), 'e_track': (0.05, 0.05),
                          'e_tilde': (0.06, 0.06)},
    ('foam_brick', 'M3-lambda'): {'e_r': (12.36, 8.02), 'e_hat': (0.14, 0.09),
                                  'e_track': (0.06, 0.04), 'e_tilde': (0.16, 0.08)},
    ('foam_brick', 'M4'): {'e_r': (12.54, 7.89), 'e_hat': (0.14, 0.09), 'e_track': (0.07, 0.04),
                           'e_tilde': (0.14, 0.09)},
    ('softball', 'M3-lambda'): {'e_r': (14.25, 6.60), 'e_hat': (0.13, 0.07),
                                'e_track': (0.07, 0.05), 'e_tilde': (0.13, 0.08)},
    ('softball', 'M4'): {'e_r': (23.87, 7.16), 'e_hat': (0.25, 0.16), 'e_track': (0.12, 0.05),
                         'e_tilde': (0.22, 0.14)},
    ('abrasive_sponge', 'M3-lambda'): {'e_r': (16.04, 7.97), 'e_hat': (0.18, 0.11),
                                       'e_track': (0.05, 0.05), 'e_tilde': (0.17, 0.13)},
    ('abrasive_sponge', 'M4'): {'e_r': (26.93, 22.01), 'e_hat': (0.25, 0.29),
                                'e_track': (0.13, 0.10), 'e_tilde': (0.25, 0.25)},
    ('bleach_cleanser', 'M3-lambda'): {'e_r': (12.42, 7.08), 'e_hat': (0.13, 0.07),
                                       'e_track': (0.07, 0.05), 'e_tilde': (0.13, 0.07)},
    ('bleach_cleanser', 'M4'): {'e_r': (19.60, 5.55), 'e_hat': (0.17, 0.10),
                                'e_track': (0.06, 0.03), 'e_tilde': (0.15, 0.12)},
}
# Sec. V-C: "an average e_tilde reduction of approximately 74 % compared to the open-loop".
E_TILDE_REDUCTION_PERCENT = 74
