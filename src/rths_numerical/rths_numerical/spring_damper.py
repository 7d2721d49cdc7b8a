"""A linear spring-damper specimen between the floor and the ground: f = k x + c v."""


class SpringDamper:
    """Stroke x [m] and velocity v [m/s] in, force k x + c v [N] out (no internal state)."""

    def __init__(self, k_n_m: float, c_n_s_m: float):
        """Set the stiffness [N/m] and the damping [N s/m]."""
        self.k, self.c = float(k_n_m), float(c_n_s_m)
        self.x = self.v = 0.0

    def reset(self):
        """Return to rest."""
        self.x = self.v = 0.0

    def advance(self, x0, v0, x1, v1, h):
        """Take the stroke and velocity at the end of the sub-step (the force follows them)."""
        self.x, self.v = x1, v1

    def force(self):
        """Return the force [N] on the table."""
        return self.k * self.x + self.c * self.v
