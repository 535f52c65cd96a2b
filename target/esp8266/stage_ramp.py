# Step timing with a constant-acceleration ramp: pure integer logic.
#
# The interval before step i (0-based) of an n-step move depends only on how far that
# step is from the nearer end of the move, so the planner keeps no state. Speed after k
# steps from rest-speed v0 with acceleration a is sqrt(v0^2 + 2 a k) (steps/s), capped at
# v_max.


def isqrt(n):
    """Integer square root (floor) by Newton's method; n >= 0."""
    if n < 0:
        raise ValueError("isqrt of negative %d" % n)
    if n < 2:
        return n
    x = n
    y = (x + 1) // 2
    while y < x:
        x = y
        y = (x + n // x) // 2
    return x


class RampPlan:
    """Intervals (us) for a move of n_steps with start rate, max rate and acceleration."""

    def __init__(self, n_steps, start_hz, max_hz, accel_hz_per_s):
        if n_steps < 0:
            raise ValueError("n_steps %d < 0" % n_steps)
        if not 0 < start_hz <= max_hz:
            raise ValueError("need 0 < start_hz (%d) <= max_hz (%d)" % (start_hz, max_hz))
        if accel_hz_per_s <= 0:
            raise ValueError("accel_hz_per_s %d must be > 0" % accel_hz_per_s)
        self.n_steps = n_steps
        self.start_hz = start_hz
        self.max_hz = max_hz
        self.accel = accel_hz_per_s

    def rate_hz(self, i):
        """Step rate for step i: ramps up from the start, down towards the end."""
        k = min(i, self.n_steps - 1 - i)
        if k < 0:
            k = 0
        vv = self.start_hz * self.start_hz + 2 * self.accel * k
        if vv >= self.max_hz * self.max_hz:
            return self.max_hz   # cruising: no square root per step
        return isqrt(vv)

    def interval_us(self, i):
        return 1000000 // self.rate_hz(i)
