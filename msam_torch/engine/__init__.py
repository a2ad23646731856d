"""The MSAM engine (paper sections 2-5): candidates (Eq. 8-9), the NLS step (Eq. 17-18) and its rules,
fitness (Eq. 19), sensitivities (Eq. 14-16), the trainer of Algorithm 1, theta re-tuning, the weak
form and the sequential reference."""
