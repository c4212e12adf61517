"""The finite-element problem: the blank's mesh, the total-Lagrangian membrane with the law at
every quadrature point, prescribed boundary motion, Newton's method and adaptive load steps."""
