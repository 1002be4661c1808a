"""No recompilation between iterations: the iterative integrators keep iteration
counters, seeds and sample indices opaque, so after the first iterations every
iteration launches only kernels that earlier iterations launched (Dr.Jit's kernel
history, read and cleared after every iteration by the progress callback, kernels
compared by hash). Across renders Dr.Jit may compile variants of the same kernels that
differ only in the alignment it assumes for input arrays (``align 64`` or ``align 1``
loads, by where numpy put the scene's tables); its disk cache then serves them. Test of
the test: an iteration whose literal changes every time (a non-opaque counter) is caught."""
import drjit as dr
import mitsuba as mi
import pytest

from mi_plugins.verify import analytic

CONFIGS = {
    # adaptive=false: the steps of the planned render only (a burn-in of 3 leaves the furnace's average
    # 1-2 % low, which the adaptive burn-in would extend, moving the final gathering's first steps)
    "ray_bundle": {"type": "ray_bundle", "chains": 8, "iterations": 10, "burn_in": 3, "adaptive": False},
    "ray_bundle+paper": {"type": "ray_bundle", "chains": 8, "iterations": 10, "burn_in": 3, "first_shot": False,
                         "average_diffuse": False, "adaptive": False},
    "stochastic_ray": {"type": "stochastic_ray", "iterations": 10, "burn_in": 3},
}


def new_kernels_per_step(scene, spp=1, seed=1):
    """For every step of a render: the number of kernels launched in it that no earlier
    step launched."""
    integrator, seen, new = scene.integrator(), set(), []

    def step(done, total):
        dr.sync_thread()
        hashes = {k["hash"] for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT}
        new.append(len(hashes - seen))
        seen.update(hashes)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        integrator.progress_callback = step
        mi.render(scene, spp=spp, seed=seed)
    finally:
        integrator.progress_callback = None
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    return new


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_no_recompilation_between_iterations(name):
    scene = analytic.furnace(0.5, 0.5, "box", resolution=8).scene(CONFIGS[name])
    new = new_kernels_per_step(scene)
    iterations = CONFIGS[name]["iterations"]
    # the first two steps of each kind compile (the iterations, the averaged ones, which
    # also image or average, and a final gathering; the second of each advances the
    # camera sampler and commits the film for the first time); no later step does
    burn_in = CONFIGS[name]["burn_in"]
    first_of_kind = {0, 1, burn_in, burn_in + 1, iterations, iterations + 1}
    late = [k for k, n in enumerate(new) if n and k not in first_of_kind]
    assert late == [], "steps %s compiled new kernels (%s)" % (late, new)


def test_a_changing_literal_is_caught(monkeypatch):
    """Test of the test: a transfer step that bakes the iteration's number into its kernel
    (ray_bundle's steps traced every iteration: a frozen step is traced once and replayed,
    so no later literal could reach it)."""
    from mi_plugins.integrators.ray_bundle import frozen, transfer
    monkeypatch.setattr(frozen, "ENABLED", False)
    calls, original = [0], transfer.Transport.transfer

    def literal(self, state):
        calls[0] += 1
        incoming, from_sky = original(self, state)
        return [x * (1.0 + 1e-7 * calls[0]) for x in incoming], from_sky     # a new literal every iteration
    monkeypatch.setattr(transfer.Transport, "transfer", literal)
    scene = analytic.furnace(0.5, 0.5, "box", resolution=8).scene(CONFIGS["ray_bundle"])
    new = new_kernels_per_step(scene)
    assert sum(1 for n in new[4:10] if n) >= 5, new
