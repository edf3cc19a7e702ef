"""The LP method's settings: its trust region, its stops, its first phase and its IRLS steps,
each with the measurement behind its value (docs/decisions/0004-lp-method.md, 0019, 0029)."""

ROT_RADIUS = 0.02  # initial trust region: radians per rotation increment
T_RADIUS = 0.05  # and metres per translation component
MAX_ITER = 40
STEP_TOL = 2e-7  # stop when no camera parameter moves by more than this (rad or m)
# stop when the LP promises less gain than this per camera parameter: the loss is ~z^2/2 in
# robust sigmas near its minimum, so a step of 0.1 standard error gains ~0.005 per parameter
CONVERGED_GAIN = 0.005
# Frames of the first phase: few enough that its LPs stay small, enough that the phase on all
# frames then needs one step. 150 ran 13-17% faster than 300 at 8 x 2000 and 16 x 3000, clean
# and with 8% outliers, with the same errors (decision 0004).
SUBSET_FRAMES = 150
SUBSET_ONLY_ABOVE = 4  # the first phase pays off only on captures this many times the subset

CONVERGED_SE = 0.05  # stop when a step moves every parameter by less than this many standard errors
# IRLS (decision 0004, third session; measured at 16 and 32 x 2000, 1 deg / 3 cm start, 8% outliers)
MAX_IRLS = 8  # inner IRLS steps on one linearisation
IRLS_DONE_SE = 0.1  # inner steps stop when one moves every parameter by less than this many standard errors
MAX_RELINEARISE = 6  # IRLS moves (each relinearised) before the LP takes over
# a move shorter than this many standard errors ends IRLS: the linearisation then changes the
# IRLS point by far less than the LP's guard (a 7 SE move left 2.6k LP pairs, as many as a 0.2 SE
# one, and saved a normal matrix and a relinearisation: 3.8 -> 2.8 s at 32 x 2000); and an LP
# step this short lands where its linearisation still holds (IRLS and LP moved 0.5-11 SE from
# the phase's linearisation at 8-32 x 2000, and one more step from there moved < 0.012 SE)
RELINEARISE_SE = 20.0
IRLS_GUARD_SE = 0.25  # the guard of an LP written about an IRLS point (IRLS stalls ~0.1 SE from the optimum)
# a row this many sigmas from a breakpoint at the IRLS point starts in the LP: 0.01 gave 8.4k
# pairs (1.4 s) at 32 x 2000 with outliers, 0.003 2.6k (0.6-0.9 s), 0.001 2.8-3.9k after more rounds.
# Since a round after the first also models the breakpoints near its point (step.WIDEN_NEAR),
# 0.002 takes 2 rounds on six 32-128 x 3000 captures, with 27-31% fewer pairs than 0.003 (11.0-11.3k
# at 128 cameras); 0.0015 took 3 rounds on two of them, 0.001 on four (decision 0029)
IRLS_NEAR_BREAK = 0.002
# the first phase's L1 optimum only starts the second phase: IRLS near it is enough, and its
# certifying LPs took 1.0-1.4 s of the 32 x 2000 time (the second phase's robust scale moved 1e-4)
CERTIFY_FIRST_PHASE = False
POINT_PARAMS = 3  # a point track's frame fixes its midpoint alone (its direction is free: calib/refine.with_tracks)
SCHEMES = ("irls", "lp")  # IRLS steps then certifying LPs (default); LP steps only (the scheme before, decision 0004)
