"""Scenes with analytically known radiance, and a statistical harness to verify
any Mitsuba integrator against them.

>>> from mi_plugins import analytic
>>> case = analytic.furnace(albedo=0.5, emission=0.5, geometry='box')
>>> res = analytic.check(case, {'type': 'path'}, spp=64, runs=8, seed=0)
>>> res.passed, res.mean, res.expected_mean, res.z, res.rmse, res.seconds
>>> grad = analytic.check_gradient(case, 'prb', 'albedo', spp=64, runs=16, mode='forward')  # dL/da = Le/(1-a)^2
"""
from .case import AnalyticCase
from .classic import bekaert, diffuse_sphere, furnace, keller_cube, mirror_sphere
from .constant_radiance import *  # noqa: F401,F403  (constant-radiance cases)
from .harness import CheckResult, check
from .gradients import GradientResult, check_gradient
from .matrix import all_cases


def cases():
    """{case name: factory} of every case in the verification matrix (defaults; factories
    accept ``resolution=``)."""
    return all_cases()
