"""URLB constants: the expert scores behind the normalised score, and the published results."""

from __future__ import annotations

#: what ``--small`` sets (of ``protocol``, ``study``, ``train`` and ``finetune``): CPU-sized networks, batches and
#: replay; an option given explicitly wins; the step counts are not changed
SMALL_SETTINGS: dict[str, int] = {"hidden_dim": 32, "batch_size": 32, "learning_starts": 500, "buffer_size": 100_000}

#: URLB's pre-training snapshots (steps)
DEFAULT_SNAPSHOTS: tuple[int, ...] = (100_000, 500_000, 1_000_000, 2_000_000)

#: expert returns of the 12 URLB tasks (normalised score = return / expert)
EXPERT_SCORES: dict[str, float] = {
    "walker_stand": 984.0,
    "walker_walk": 971.0,
    "walker_run": 796.0,
    "walker_flip": 799.0,
    "quadruped_walk": 866.0,
    "quadruped_run": 888.0,
    "quadruped_stand": 920.0,
    "quadruped_jump": 888.0,
    "jaco_reach_top_left": 191.0,
    "jaco_reach_top_right": 223.0,
    "jaco_reach_bottom_left": 193.0,
    "jaco_reach_bottom_right": 203.0,
}

#: the rl-zoo names of a method's variants (each with its own yaml, ``zoo_configs/<name>.yml``), each with the rl-zoo
#: name of the method it runs; ``cic_code``: CIC as the reference code runs it, set beside Table 6's CIC
METHOD_VARIANTS: dict[str, str] = {"cic_code": "cic"}

#: the CIC paper's Table 5 (state-based URLB, 2M pre-training, 100k fine-tuning, 10 seeds x 12 tasks): rliable's
#: aggregates of normalised scores, ``{method: {metric: value}}``; only CIC's four are published, the others' IQM
PUBLISHED_AGGREGATES: dict[str, dict[str, float]] = {
    "cic": {"IQM": 0.77, "Median": 0.76, "Mean": 0.76, "Optimality Gap": 0.24},
    "apt": {"IQM": 0.65},
    "protorl": {"IQM": 0.65},
    "rnd": {"IQM": 0.61},
    "disagreement": {"IQM": 0.51},
    "aps": {"IQM": 0.43},
    "icm": {"IQM": 0.41},
    "diayn": {"IQM": 0.40},
    "smm": {"IQM": 0.25},
}


#: the CIC paper's Table 6 (URLB's code, 2M pre-training steps, 100k fine-tuning, 10 seeds): the final return of
#: each method on each task, ``{method: {task: (mean, standard error)}}``; ``ddpg``: from scratch
PUBLISHED_RETURNS: dict[str, dict[str, tuple[float, float]]] = {
    "ddpg": {
        "walker_flip": (538, 27),
        "walker_run": (325, 25),
        "walker_stand": (899, 23),
        "walker_walk": (748, 47),
        "quadruped_jump": (236, 48),
        "quadruped_run": (157, 31),
        "quadruped_stand": (392, 73),
        "quadruped_walk": (229, 57),
        "jaco_reach_bottom_left": (72, 22),
        "jaco_reach_bottom_right": (117, 18),
        "jaco_reach_top_left": (116, 22),
        "jaco_reach_top_right": (94, 18),
    },
    "cic": {
        "walker_flip": (631, 34),
        "walker_run": (486, 25),
        "walker_stand": (959, 2),
        "walker_walk": (885, 28),
        "quadruped_jump": (595, 42),
        "quadruped_run": (505, 47),
        "quadruped_stand": (761, 54),
        "quadruped_walk": (723, 43),
        "jaco_reach_bottom_left": (138, 9),
        "jaco_reach_bottom_right": (145, 7),
        "jaco_reach_top_left": (153, 7),
        "jaco_reach_top_right": (163, 4),
    },
    "icm": {
        "walker_flip": (417, 16),
        "walker_run": (247, 21),
        "walker_stand": (859, 23),
        "walker_walk": (627, 42),
        "quadruped_jump": (178, 35),
        "quadruped_run": (110, 18),
        "quadruped_stand": (312, 68),
        "quadruped_walk": (126, 27),
        "jaco_reach_bottom_left": (111, 11),
        "jaco_reach_bottom_right": (97, 9),
        "jaco_reach_top_left": (82, 14),
        "jaco_reach_top_right": (103, 11),
    },
    "disagreement": {
        "walker_flip": (346, 13),
        "walker_run": (208, 15),
        "walker_stand": (746, 34),
        "walker_walk": (549, 37),
        "quadruped_jump": (389, 62),
        "quadruped_run": (337, 30),
        "quadruped_stand": (512, 89),
        "quadruped_walk": (293, 37),
        "jaco_reach_bottom_left": (124, 7),
        "jaco_reach_bottom_right": (115, 10),
        "jaco_reach_top_left": (106, 12),
        "jaco_reach_top_right": (139, 7),
    },
    "rnd": {
        "walker_flip": (474, 39),
        "walker_run": (406, 30),
        "walker_stand": (911, 5),
        "walker_walk": (704, 30),
        "quadruped_jump": (637, 12),
        "quadruped_run": (459, 6),
        "quadruped_stand": (766, 43),
        "quadruped_walk": (536, 39),
        "jaco_reach_bottom_left": (110, 5),
        "jaco_reach_bottom_right": (117, 7),
        "jaco_reach_top_left": (99, 6),
        "jaco_reach_top_right": (100, 6),
    },
    "apt": {
        "walker_flip": (544, 14),
        "walker_run": (392, 26),
        "walker_stand": (942, 6),
        "walker_walk": (773, 70),
        "quadruped_jump": (648, 18),
        "quadruped_run": (492, 14),
        "quadruped_stand": (872, 23),
        "quadruped_walk": (770, 47),
        "jaco_reach_bottom_left": (103, 8),
        "jaco_reach_bottom_right": (100, 6),
        "jaco_reach_top_left": (73, 12),
        "jaco_reach_top_right": (90, 10),
    },
    "protorl": {
        "walker_flip": (456, 12),
        "walker_run": (306, 13),
        "walker_stand": (917, 27),
        "walker_walk": (792, 41),
        "quadruped_jump": (617, 44),
        "quadruped_run": (373, 33),
        "quadruped_stand": (716, 56),
        "quadruped_walk": (412, 54),
        "jaco_reach_bottom_left": (129, 8),
        "jaco_reach_bottom_right": (132, 8),
        "jaco_reach_top_left": (123, 9),
        "jaco_reach_top_right": (159, 7),
    },
    "smm": {
        "walker_flip": (450, 24),
        "walker_run": (426, 26),
        "walker_stand": (924, 12),
        "walker_walk": (770, 44),
        "quadruped_jump": (96, 7),
        "quadruped_run": (96, 6),
        "quadruped_stand": (123, 11),
        "quadruped_walk": (80, 6),
        "jaco_reach_bottom_left": (45, 7),
        "jaco_reach_bottom_right": (46, 11),
        "jaco_reach_top_left": (36, 3),
        "jaco_reach_top_right": (47, 6),
    },
    "diayn": {
        "walker_flip": (319, 17),
        "walker_run": (158, 8),
        "walker_stand": (695, 46),
        "walker_walk": (498, 27),
        "quadruped_jump": (660, 43),
        "quadruped_run": (433, 29),
        "quadruped_stand": (851, 43),
        "quadruped_walk": (576, 81),
        "jaco_reach_bottom_left": (39, 6),
        "jaco_reach_bottom_right": (38, 5),
        "jaco_reach_top_left": (19, 4),
        "jaco_reach_top_right": (28, 6),
    },
    "aps": {
        "walker_flip": (465, 20),
        "walker_run": (134, 16),
        "walker_stand": (721, 44),
        "walker_walk": (527, 79),
        "quadruped_jump": (463, 51),
        "quadruped_run": (281, 17),
        "quadruped_stand": (542, 53),
        "quadruped_walk": (436, 79),
        "jaco_reach_bottom_left": (76, 8),
        "jaco_reach_bottom_right": (88, 11),
        "jaco_reach_top_left": (68, 6),
        "jaco_reach_top_right": (76, 10),
    },
}

#: MOSS's README (LeapLabTHU/MOSS): MOSS and its own re-run of CIC, ``{method: {task: (mean, standard error)}}``
#: (11 tasks: no jaco reach top right)
MOSS_PUBLISHED_RETURNS: dict[str, dict[str, tuple[float, float]]] = {
    "moss": {
        "walker_flip": (729, 40),
        "walker_run": (531, 20),
        "walker_stand": (962, 3),
        "walker_walk": (942, 5),
        "quadruped_jump": (674, 11),
        "quadruped_run": (485, 6),
        "quadruped_stand": (911, 11),
        "quadruped_walk": (635, 36),
        "jaco_reach_bottom_left": (151, 5),
        "jaco_reach_bottom_right": (150, 5),
        "jaco_reach_top_left": (150, 5),
    },
    "cic": {
        "walker_flip": (715, 40),
        "walker_run": (535, 25),
        "walker_stand": (968, 2),
        "walker_walk": (914, 12),
        "quadruped_jump": (541, 31),
        "quadruped_run": (376, 19),
        "quadruped_stand": (717, 46),
        "quadruped_walk": (460, 36),
        "jaco_reach_bottom_left": (147, 8),
        "jaco_reach_bottom_right": (150, 6),
        "jaco_reach_top_left": (145, 9),
    },
}


def normalized_score(task: str, episode_return: float) -> float:
    """URLB normalised score: ``return / expert score`` (no random baseline subtracted).

    :param task: URLB task name, e.g. ``walker_flip``
    :param episode_return: mean episode return
    """
    if task not in EXPERT_SCORES:
        raise ValueError(f"no expert score for task {task!r}; known: {sorted(EXPERT_SCORES)}")
    return float(episode_return) / EXPERT_SCORES[task]
