"""Intervals the experiment tables share (scripts/recipe_tables.py, scripts/section7_table.py): the
mean of a sample and the half width of its two-sided 95 % Student-t interval."""
import math

# Two-sided 95 % quantiles of Student's t by degrees of freedom (1.96 beyond 10: the normal's).
T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262, 10: 2.228}


def mean_ci(values):
    """(mean, half width of the 95 % interval); the half width is NaN for fewer than 2 values."""
    n = len(values)
    m = sum(values) / n
    if n < 2:
        return m, float("nan")
    sd = math.sqrt(sum((x - m) ** 2 for x in values) / (n - 1))
    return m, T975.get(n - 1, 1.96) * sd / math.sqrt(n)
