"""A linear spring-damper specimen between the floor and the ground: f = k x + c v (+ m a)."""


class SpringDamper:
    """Stroke x [m] and velocity v [m/s] in, force k x + c v + m a [N] out.

    ``m_kg``: an optional mass moving with the floor (its acceleration ``a`` over each
    sub-step from the velocities); the numerical substructure adds its ground term
    (relative frame, seed eq. 24: ``specimen_mass_kg``).
    """

    def __init__(self, k_n_m: float, c_n_s_m: float, m_kg: float = 0.0):
        """Set the stiffness [N/m], the damping [N s/m] and the moving mass [kg]."""
        self.k, self.c, self.m = float(k_n_m), float(c_n_s_m), float(m_kg)
        self.x = self.v = self.a = 0.0

    def reset(self):
        """Return to rest."""
        self.x = self.v = self.a = 0.0

    def advance(self, x0, v0, x1, v1, h):
        """Take the stroke and velocity at the end of the sub-step (the force follows them)."""
        self.x, self.v = x1, v1
        self.a = (v1 - v0) / h

    def force(self):
        """Return the force [N] on the table."""
        return self.k * self.x + self.c * self.v + self.m * self.a
