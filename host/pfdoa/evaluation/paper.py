"""The paper's Table I (Latif & Parasuraman), copied for side-by-side comparison.

Values are (RMSE m, sd m, TPI ms, TPI sd ms) exactly as printed, including the paper's
own inconsistencies (e.g. the WCL "Average" of Dataset 0 is 2.47 while its three rows
average 1.47). PF-DOA on Dataset 0 has separate numbers without and with odometry; our
rows "(no odom)" are compared with the former and the odometry rows with the latter.
The robot traces are not part of Table I.
"""

from __future__ import annotations

Entry = tuple[float, float, float, float]

# method keys follow pfdoa.estimators.METHODS; "pf-doa/no-odom" is the paper's wo/ odom row.
TABLE_I: dict[str, dict[str, dict[str, Entry]]] = {
    "dataset0": {
        "Diagonal": {
            "trilateration": (1.03, 0.45, 71, 20), "wcl": (1.36, 0.76, 61, 18), "drssi": (0.42, 0.09, 42, 17),
            "markov": (0.08, 0.01, 105, 29), "pf-doa/no-odom": (0.10, 0.01, 49, 13), "pf-doa": (0.08, 0.01, 66, 11),
        },
        "Inside": {
            "trilateration": (1.41, 0.57, 68, 18), "wcl": (1.43, 0.81, 53, 21), "drssi": (0.53, 0.12, 52, 13),
            "markov": (0.09, 0.015, 99, 33), "pf-doa/no-odom": (0.12, 0.08, 53, 14), "pf-doa": (0.10, 0.07, 65, 21),
        },
        "Boundary": {
            "trilateration": (1.23, 0.68, 77, 16), "wcl": (1.62, 0.96, 63, 23), "drssi": (0.72, 0.18, 48, 16),
            "markov": (0.21, 0.09, 112, 38), "pf-doa/no-odom": (0.36, 0.08, 51, 12), "pf-doa": (0.26, 0.07, 62, 18),
        },
        "Average": {
            "trilateration": (1.22, 0.56, 72, 18), "wcl": (2.47, 0.84, 59, 20), "drssi": (0.55, 0.13, 47, 15),
            "markov": (0.13, 0.04, 105, 100), "pf-doa/no-odom": (0.19, 0.05, 51, 13), "pf-doa": (0.15, 0.05, 64, 16),
        },
    },
    "dataset1": {
        "Wi-Fi": {
            "trilateration": (2.74, 1.79, 69, 18), "wcl": (3.83, 1.85, 76, 21), "drssi": (2.21, 1.24, 89, 25),
            "markov": (1.52, 0.54, 202, 75), "pf-doa": (1.07, 0.46, 95, 30),
        },
        "BLE": {
            "trilateration": (2.33, 1.62, 75, 16), "wcl": (3.76, 0.81, 83, 17), "drssi": (1.90, 0.91, 69, 10),
            "markov": (1.32, 0.07, 195, 79), "pf-doa": (1.18, 0.24, 72, 20),
        },
        "Zigbee": {
            "trilateration": (3.03, 1.93, 78, 14), "wcl": (4.21, 0.21, 65, 12), "drssi": (2.42, 1.64, 79, 15),
            "markov": (1.89, 0.98, 215, 98), "pf-doa": (1.26, 0.74, 82, 25),
        },
        "Average": {
            "trilateration": (2.70, 1.78, 74, 16), "wcl": (3.94, 0.95, 73, 16), "drssi": (2.18, 1.26, 79, 17),
            "markov": (1.58, 0.53, 204, 84), "pf-doa": (1.17, 0.48, 83, 25),
        },
    },
    # Only the diagonal points of Dataset 2 are public in the authors' repository.
    "dataset2": {
        "Channel 0": {
            "trilateration": (2.91, 1.67, 82, 21), "wcl": (3.81, 2.02, 94, 29), "drssi": (2.01, 1.14, 78, 11),
            "markov": (1.42, 0.09, 270, 113), "pf-doa": (0.39, 0.08, 120, 30),
        },
        "Channel 39": {
            "trilateration": (3.22, 1.21, 84, 34), "wcl": (4.98, 2.45, 92, 35), "drssi": (3.12, 2.01, 89, 23),
            "markov": (1.42, 0.09, 270, 113), "pf-doa": (1.99, 0.41, 132, 41),
        },
        "Channels 0-39": {
            "trilateration": (3.03, 2.41, 91, 22), "wcl": (4.13, 2.92, 84, 31), "drssi": (2.91, 1.37, 98, 11),
            "markov": (1.72, 0.61, 310, 129), "pf-doa": (1.89, 0.81, 112, 35),
        },
    },
}


def paper_entry(block: str, experiment: str, method: str, use_odometry: bool) -> Entry | None:
    """The paper's number for one of our rows, or None.

    pf-doa and pf-doa-paper rows both compare with the paper's PF-DOA (the paper has one
    implementation); on Dataset 0 the "(no odom)" rows take its wo/ odom numbers.
    """
    cells = TABLE_I.get(block, {}).get(experiment)
    if cells is None:
        return None
    key = "pf-doa" if method in ("pf-doa", "pf-doa-paper") else method
    if key == "pf-doa" and not use_odometry and "pf-doa/no-odom" in cells:
        key = "pf-doa/no-odom"
    return cells.get(key)
