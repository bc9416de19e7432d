"""The one registry type (fitlab/registry.py) and the registries built on it."""

from __future__ import annotations

import pytest

from fitlab.registry import Registry


def test_a_registry_is_a_read_only_mapping_in_registration_order():
    reg = Registry("loss", {"chi2": 1, "relative": 2})
    assert list(reg) == ["chi2", "relative"] and reg.names() == ("chi2", "relative")
    assert reg["chi2"] == 1 and "log" not in reg and len(reg) == 2
    assert not hasattr(reg, "__setitem__")


def test_an_unknown_name_gets_a_did_you_mean_and_the_list():
    reg = Registry("microfacet distribution", {"ggx": 1, "beckmann": 2, "beckmann_rational": 3},
                   listing="`fitlab models`")
    with pytest.raises(ValueError) as exc:
        reg.validate("bekmann")
    msg = str(exc.value)
    assert msg.startswith("unknown microfacet distribution 'bekmann'; did you mean 'beckmann'")
    assert "Microfacet distributions: ggx, beckmann, beckmann_rational (see `fitlab models`)" in msg
    assert "did you mean" not in str(reg.unknown("zzz"))
    assert reg.validate("ggx") == "ggx" and reg.get_entry("beckmann") == 2
    assert "Losses:" in str(Registry("loss", {"a": 1}).unknown("b"))


def test_register_needs_replace_for_a_taken_name():
    reg = Registry("writer", {"csv": 1})
    reg.register("exr", 2)
    assert reg.names() == ("csv", "exr")
    with pytest.raises(ValueError, match="already registered; pass replace=True"):
        reg.register("csv", 3)
    reg.register("csv", 3, replace=True)
    assert reg["csv"] == 3
    assert reg.unregister("csv") == 3 and "csv" not in reg and reg.unregister("csv") is None
    with pytest.raises(ValueError, match="non-empty name"):
        reg.register("", 4)


def test_the_registries_are_registries():
    from fitlab.export.renderers import EXPORTERS
    from fitlab.export.writers import WRITERS
    from fitlab.fitting.losses import LOSSES
    from fitlab.fitting.samplers import SAMPLERS
    from fitlab.lut.kinds import KINDS
    from fitlab.microfacet import DISTRIBUTIONS, REGISTRY
    from fitlab.models import CONSTRUCTORS, MODELS
    from fitlab.models.presets import PRESETS
    from fitlab.phase import PHASE_FUNCTIONS
    from fitlab.simulate.components import BOUNDARIES, PHASES
    from fitlab.tradeoffs.knobs import KNOBS

    for reg in (EXPORTERS, WRITERS, LOSSES, SAMPLERS, KINDS, DISTRIBUTIONS, REGISTRY, MODELS,
                CONSTRUCTORS, PRESETS, PHASE_FUNCTIONS, BOUNDARIES, PHASES, KNOBS):
        assert isinstance(reg, Registry), reg
        assert reg.names() and all(isinstance(n, str) for n in reg.names())


def test_a_model_carries_its_structure():
    """Sums, layered models and renderer translations are fields of the Model (read by the
    exporters, the lobe fit, the tradeoffs' variants) rather than parsed from its name."""
    from fitlab.models import get_model, variant_name
    from fitlab.models.spongecake import stack_kinds

    two = get_model("rough_conductor+rough_conductor")
    assert [t.model.name for t in two.terms] == ["rough_conductor", "rough_conductor"]
    assert set(two.terms[0].parameter_names) | set(two.terms[1].parameter_names) == \
        set(two.parameter_names)
    assert set(two.terms[0].parameter_names).isdisjoint(two.terms[1].parameter_names)
    coated = get_model("coated(lambertian)")
    assert coated.inner[0].model is get_model("lambertian")
    assert coated.argument("specular") == "delta" and coated.translation("mitsuba") == "plastic"
    assert get_model("coated(rough_conductor)").translation("mitsuba") is None
    assert get_model("rough_conductor").translation("mitsuba") == "roughconductor"
    assert get_model("lambertian").terms == () == get_model("lambertian").inner
    sponge = get_model("spongecake(fiber, surface_z)")
    assert stack_kinds(sponge) == ("fiber", "surface_z") and sponge.argument("multiple") is None
    assert get_model("spongecake(fiber,substrate=lambertian)").inner[0].model.name == "lambertian"
    learned = variant_name(sponge, "multiple", "learned")
    assert get_model(learned).argument("multiple") == "learned"
    assert variant_name(get_model(learned), "multiple", None) == "spongecake(fiber,surface_z)"
    assert variant_name(get_model("lambertian"), "multiple", "lobe") is None
