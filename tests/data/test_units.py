"""Channel units: read from a store's attributes, shown in labels."""

from robomorph.data.units import channel_label, channel_units


def test_units_come_from_the_attributes_when_they_match_the_channels():
    attrs = {"y_names": ["q0", "q1"], "y_units": ["rad", "rad"], "u_names": ["t0", "t1"], "u_units": ["N m"]}
    assert channel_units(attrs, "y") == ["rad", "rad"]
    assert channel_units(attrs, "u") == ["", ""]  # a count that does not match says nothing
    assert channel_units({"y_names": ["a"]}, "y") == [""]


def test_labels_carry_the_unit_only_when_known():
    assert channel_label("q1", "rad") == "q1 [rad]"
    assert channel_label("q1", "") == "q1"
