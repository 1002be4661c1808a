"""Base class of this package's area emitters with direction-dependent radiance.

Subclasses implement ``radiance(si, wo, active)``: the emitted radiance at the
surface point ``si`` in the LOCAL outgoing direction ``wo`` (upper hemisphere),
and may override ``sample_outgoing(si, sample, active) -> (wo, pdf)`` (default:
cosine-weighted). The base class provides what Mitsuba's integrators call:
``eval`` (direct hits), ``sample_direction``/``pdf_direction`` (next-event
estimation), ``sample_ray`` (light tracing), ``sample_position`` and
``sample_wavelengths`` (the particle tracer's direct connection to the camera,
which passes the WORLD direction toward the camera in ``si.wi``).
Positions are sampled uniformly by area on the emitting shape.

Scene parameters: subclasses expose their parameters in ``traverse`` and implement
``_exposed()`` and ``_apply(p, keys)``; ``parameters_changed`` (:mod:`mi_plugins.base.editable`)
checks an edit exactly as at load and undoes an invalid one.
"""
import drjit as dr
import mitsuba as mi

from mi_plugins.base import editable


class SurfaceEmitter(mi.Emitter):
    #: the Mitsuba plugin name (messages of the parameter reader)
    plugin = None

    def __init__(self, props):
        super().__init__(props)
        self.m_flags = mi.EmitterFlags.Surface | mi.EmitterFlags.SpatiallyVarying

    # ---------------------------------------------------------- scene parameters
    def _exposed(self):
        raise NotImplementedError

    def _apply(self, p, keys):
        raise NotImplementedError

    def _notify(self):
        """After a valid edit: tell the plugins that depend on this emitter (none here)."""

    def _keep_valid(self):
        editable.keep_valid(self)

    def parameters_changed(self, keys=()):
        editable.parameters_changed(self, keys)

    def undo(self, notify=True):
        """Back to the last valid values, and what depends on them."""
        editable.undo(self, notify)

    # ---------------------------------------------------------- to implement
    def radiance(self, si, wo, active):
        raise NotImplementedError

    def sample_outgoing(self, si, sample, active):
        wo = mi.warp.square_to_cosine_hemisphere(sample)
        return wo, mi.warp.square_to_cosine_hemisphere_pdf(wo)

    # ---------------------------------------------------------- Mitsuba interface
    def _shape(self):
        shape = self.get_shape()
        if shape is None:
            raise RuntimeError("%s: this emitter must be attached to a shape (nest it inside a <shape>)"
                               % type(self).__name__)
        return shape

    def eval(self, si, active=True):
        wo = si.wi
        active = mi.Bool(active) & (mi.Frame3f.cos_theta(wo) > 0)
        return dr.select(active, self.radiance(si, wo, active), 0.0)

    def sample_direction(self, it, sample, active=True):
        ds = self._shape().sample_direction(it, sample, active)
        active = mi.Bool(active) & (dr.dot(ds.d, ds.n) < 0) & (ds.pdf != 0)
        si = mi.SurfaceInteraction3f(ds, it.wavelengths)
        si.wi = si.to_local(-ds.d)
        value = self.radiance(si, si.wi, active) / dr.select(active, ds.pdf, 1.0)
        ds.emitter = mi.EmitterPtr(self)
        return ds, dr.select(active, value, 0.0)

    def pdf_direction(self, it, ds, active=True):
        pdf = self._shape().pdf_direction(it, ds, active)
        return dr.select(mi.Bool(active) & (dr.dot(ds.d, ds.n) < 0), pdf, 0.0)

    def eval_direction(self, it, ds, active=True):
        si = mi.SurfaceInteraction3f(ds, it.wavelengths)
        si.wi = si.to_local(-ds.d)
        active = mi.Bool(active) & (mi.Frame3f.cos_theta(si.wi) > 0)
        return dr.select(active, self.radiance(si, si.wi, active), 0.0)

    def sample_position(self, time, sample, active=True):
        ps = self._shape().sample_position(time, sample, active)
        return ps, dr.select(ps.pdf > 0, dr.rcp(ps.pdf), 0.0)

    def pdf_position(self, ps, active=True):
        return self._shape().pdf_position(ps, active)

    def sample_wavelengths(self, si, sample, active=True):
        # Called by the particle tracer with si.wi = WORLD direction toward the camera.
        local = mi.SurfaceInteraction3f(si)
        local.wi = mi.Frame3f(si.n).to_local(si.wi)
        local.sh_frame = mi.Frame3f(si.n)
        active = mi.Bool(active) & (mi.Frame3f.cos_theta(local.wi) > 0)
        value = dr.select(active, self.radiance(local, local.wi, active), 0.0)
        return dr.zeros(mi.Color0f), value

    def sample_ray(self, time, wavelength_sample, sample2, sample3, active=True):
        ps = self._shape().sample_position(time, sample2, active)
        si = mi.SurfaceInteraction3f(ps, dr.zeros(mi.Color0f))
        wo, pdf_dir = self.sample_outgoing(si, sample3, active)
        si.wi = wo
        active = mi.Bool(active) & (pdf_dir > 0) & (ps.pdf > 0) & (mi.Frame3f.cos_theta(wo) > 0)
        weight = self.radiance(si, wo, active) * mi.Frame3f.cos_theta(wo) / dr.select(active, pdf_dir * ps.pdf, 1.0)
        ray = si.spawn_ray(si.to_world(wo))
        ray.time = time
        return ray, dr.select(active, weight, 0.0)

    def bbox(self):
        return self._shape().bbox()
