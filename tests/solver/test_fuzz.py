"""bench/fuzz.py on a few hundred random full-body problems (tests/helpers/random_bodies.py): no error on valid input,
no NaN output, every bone length and head offset kept within 1e-9, each sampled frame alone the bits of its row of
the batch, and every NaN or inf input refused with one SolverInputError line. No time is checked."""

from bench import fuzz


def test_fuzz_quick():
    report = fuzz.run(problems=300, batch=20, sample=1, bad=35, seed=1)
    assert report["problems"] == 300
    assert report["errors"] == 0, report["error_cases"]
    assert report["nan_outputs"] == 0, report["nan_cases"]
    assert 0.0 < report["max_relative_length_change"] <= fuzz.LENGTH_TOLERANCE
    assert report["single_vs_batch_mismatches"] == 0 and report["timing"]["singles_timed"] == 15
    assert report["bad_inputs"] == {"refused": 35}, (report["bad_inputs"], report["bad_inputs_solved"])
    # The problems reach every kind of answer.
    assert {"reached", "unreachable", "limited", "blocked", "unconstrained"} <= set(report["statuses"])
    assert set(report["target_kinds"]) == set(fuzz.random_bodies.KINDS)
