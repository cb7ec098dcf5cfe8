"""The seeded simulated building: frames with ground truth, and the scorer of transitions.

One place for the demo, the evaluation and the tests: ``building`` (floor plans),
``simulator`` (robots walking with a laser-like sensor; files), ``groundtruth`` (recall,
precision and latency against the true room changes).
"""
