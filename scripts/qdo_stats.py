"""Intervals the experiment tables share (scripts/recipe_tables.py, scripts/section7_table.py): the
mean of a sample and the half width of its two-sided 95 % Student-t interval."""
import math

# Two-sided 95 % quantiles of Student's t by degrees of freedom; between two listed, the lower
# one's (the wider interval); 1.96 beyond 120 (the normal's).
T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262, 10: 2.228,
        11: 2.201, 12: 2.179, 13: 2.160, 14: 2.145, 15: 2.131, 16: 2.120, 17: 2.110, 18: 2.101, 19: 2.093,
        20: 2.086, 25: 2.060, 30: 2.042, 40: 2.021, 60: 2.000, 120: 1.980}


def t975(df):
    """The two-sided 95 % quantile of Student's t with df degrees of freedom (df >= 1)."""
    if df > 120:
        return 1.96
    return T975[max(k for k in T975 if k <= df)]


def mean_ci(values):
    """(mean, half width of the 95 % interval); the half width is NaN for fewer than 2 values."""
    n = len(values)
    m = sum(values) / n
    if n < 2:
        return m, float("nan")
    sd = math.sqrt(sum((x - m) ** 2 for x in values) / (n - 1))
    return m, t975(n - 1) * sd / math.sqrt(n)
