"""``forest_product``: the product of two textures, ``a(si) · b(si)``.

Mitsuba 3.9.1 has no texture arithmetic.  The renderer uses this to multiply
a species' own colour texture (looked up by uv) by the colour-map grid
(looked up by world position) in the JIT variants, where a Python texture is
traced once and costs nothing per sample.
"""

from __future__ import annotations

NAME = "forest_product"


def make_class(mi):
    class ProductTexture(mi.Texture):
        def __init__(self, props):
            mi.Texture.__init__(self, props)
            self.a = props.get_unbounded_texture("a")
            self.b = props.get_unbounded_texture("b")

        def eval(self, si, active=True):
            return self.a.eval(si, active) * self.b.eval(si, active)

        def eval_1(self, si, active=True):
            return self.a.eval_1(si, active) * self.b.eval_1(si, active)

        def mean(self):
            return self.a.mean() * self.b.mean()

        def is_spatially_varying(self):
            return True

        def traverse(self, callback):
            callback.put("a", self.a, mi.ParamFlags.Differentiable)
            callback.put("b", self.b, mi.ParamFlags.Differentiable)

        def to_string(self):
            return f"ProductTexture[a={self.a}, b={self.b}]"

    return ProductTexture


def register(mi) -> None:
    cls = make_class(mi)
    mi.register_texture(NAME, lambda props: cls(props))
