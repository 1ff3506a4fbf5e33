"""The numbers the paper prints (Tables I, II, IV; Sections V-A/V-B and the appendix) that reports set ours beside."""

from __future__ import annotations

from typing import Any

__all__ = ["PAPER"]

PAPER: dict[str, Any] = {
    "point-mass": {"true_weights": [1, -10, -100, -1], "nominal_weights": [1, 0, 0, -1], "authors_init_range": (-30, -1),
                   "margins": {"m12": 0.0, "m23": 2.9, "m13": 6.0}, "relation": [1, 4], "demos_per_group": 60},
    "fetch-reach": {"true_weights": [0.1, -20, -100, -5], "nominal_weights": [0.1, 0, 0, -5], "authors_init_range": (-100, -10),
                    "margins": {"m12": 1.0, "m23": 1.5, "m13": 2.5}, "relation": [1, 1], "demos_per_group": 60},
    "halfcheetah": {"wall": 8.0, "penalty": -50.0, "cmse": (0.073, 0.12), "runtime_s": (3298, 659),
                    "icl_cmse": (69.74, 0.40), "icl_runtime_s": (20650, 2982),
                    "sensitivity": {20: (50.68, 98.68), 50: (0.13, 0.17), 100: (0.073, 0.12), 200: (0.017, 0.017)}},
    "ant": {"wall": 10.0, "penalty": -100.0, "cmse": (0.20, 0.29), "runtime_s": (3165, 12),
            "icl_cmse": (103.37, 0.21), "icl_runtime_s": (22703, 2961),
            "sensitivity": {20: (0.78, 0.54), 50: (0.41, 0.41), 100: (0.20, 0.29), 200: (0.011, 0.009)}},
    "hyperparameters": {"iterations": 400_000, "sigma": 0.1, "f_s_nav": 4, "f_s_wall": 3, "sigma1_wall": 1.0,
                        "sigma2_wall": 0.5},
}
