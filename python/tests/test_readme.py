"""The README's Python lines, as written there (tests/readme.rs keeps the README's block a
verbatim piece of this file); they run when pytest imports the file."""

import tensegrity
eq = tensegrity.statics("bundled:prism3")            # eq.tensions: numpy, N
run = tensegrity.dynamic("bundled:prism3", duration=2.0)
print(run["time_s"][-1], run["ring_tension_N"][-1])  # the time history's columns as arrays


def test_the_readmes_lines_give_the_equilibrium_and_the_deployment():
    assert eq.stable and eq.tensions.shape == (4,) and (eq.tensions > 0).all()
    assert run["time_s"][-1] == 2.0 and len(run) == 2001 and run["ring_tension_N"][-1] > 0
