"""Device models for the MTConnect tests: a laser cutter as the gateway will describe it, at any size."""

from __future__ import annotations

from gateway.codecs.mtconnect.model import (
    Catalog,
    Category,
    Component,
    DataItem,
    Description,
    Device,
    Representation,
)

S, E, C = Category.SAMPLE, Category.EVENT, Category.CONDITION


def laser(index: int = 1, items: int = 60) -> Device:
    """Machine `m<index>`: availability, e-stop, three linear axes, a controller path, a laser, and
    enough extra temperature samples and variables to reach `items` data items in all."""
    p = f"m{index}"
    device_items = (
        DataItem(f"{p}_avail", E, "AVAILABILITY", name="avail"),
        DataItem(f"{p}_estop", E, "EMERGENCY_STOP", name="estop"),
        DataItem(f"{p}_asset_chg", E, "ASSET_CHANGED", discrete=True),
        DataItem(f"{p}_asset_rem", E, "ASSET_REMOVED", discrete=True),
    )
    axes = tuple(
        Component(
            "Linear",
            f"{p}_{axis.lower()}",
            name=axis,
            native_name=f"{axis}1",
            data_items=(
                DataItem(
                    f"{p}_{axis}pos",
                    S,
                    "POSITION",
                    name=f"{axis}act",
                    sub_type="ACTUAL",
                    units="MILLIMETER",
                    native_units="MILLIMETER",
                    source=f"{axis}act",
                ),
                DataItem(
                    f"{p}_{axis}cmd",
                    S,
                    "POSITION",
                    name=f"{axis}cmd",
                    sub_type="COMMANDED",
                    units="MILLIMETER",
                ),
                DataItem(
                    f"{p}_{axis}feed",
                    S,
                    "AXIS_FEEDRATE",
                    sub_type="ACTUAL",
                    units="MILLIMETER/SECOND",
                    native_units="MILLIMETER/MINUTE",
                    native_scale=60.0,
                ),
                DataItem(f"{p}_{axis}load", S, "LOAD", units="PERCENT"),
                DataItem(f"{p}_{axis}travel", C, "POSITION", name=f"{axis}travel"),
            ),
        )
        for axis in ("X", "Y", "Z")
    )
    path = Component(
        "Path",
        f"{p}_path",
        name="path1",
        data_items=(
            DataItem(f"{p}_exec", E, "EXECUTION", name="execution"),
            DataItem(f"{p}_mode", E, "CONTROLLER_MODE", name="mode"),
            DataItem(f"{p}_program", E, "PROGRAM", name="program", sub_type="ACTIVE"),
            DataItem(f"{p}_block", E, "BLOCK", name="block"),
            DataItem(f"{p}_line", E, "LINE_NUMBER", sub_type="INCREMENTAL"),
            DataItem(f"{p}_parts", E, "PART_COUNT", sub_type="ALL"),
            DataItem(f"{p}_feed", S, "PATH_FEEDRATE", sub_type="ACTUAL", units="MILLIMETER/SECOND"),
            DataItem(f"{p}_feed_ovr", E, "PATH_FEEDRATE_OVERRIDE", sub_type="PROGRAMMED"),
            DataItem(f"{p}_pathpos", S, "PATH_POSITION", units="MILLIMETER_3D", coordinate_system="WORK"),
            DataItem(f"{p}_motion", C, "MOTION_PROGRAM", name="motion"),
            DataItem(f"{p}_logic", C, "LOGIC_PROGRAM", name="logic"),
        ),
    )
    controller = Component(
        "Controller",
        f"{p}_ctl",
        name="controller",
        data_items=(
            DataItem(f"{p}_system", C, "SYSTEM", name="system"),
            DataItem(f"{p}_comms", C, "COMMUNICATIONS"),
        ),
        components=(path,),
    )
    laser_items = [
        DataItem(f"{p}_power", S, "WATTAGE", name="laser_power", sub_type="ACTUAL", units="WATT"),
        DataItem(f"{p}_power_set", S, "WATTAGE", sub_type="COMMANDED", units="WATT"),
        DataItem(f"{p}_power_state", E, "POWER_STATE", name="laser_on"),
        DataItem(
            f"{p}_vib", S, "DISPLACEMENT", representation=Representation.TIME_SERIES, units="MILLIMETER"
        ),
    ]
    fixed = (
        len(device_items)
        + 5 * len(axes)
        + len(path.data_items)
        + len(controller.data_items)
        + len(laser_items)
    )
    extra = max(0, items - fixed)
    for n in range(extra):
        if n % 2:
            laser_items.append(DataItem(f"{p}_var{n}", E, "VARIABLE", name=f"var{n}"))
        else:
            laser_items.append(DataItem(f"{p}_temp{n}", S, "TEMPERATURE", units="CELSIUS"))
    power = Component("ProcessPower", f"{p}_laser", name="laser", data_items=tuple(laser_items))
    return Device(
        id=p,
        name=f"laser{index}",
        uuid=f"urn:example:laser:{index}",
        description=Description(
            manufacturer="Example", model="LC-3015", serial_number=str(1000 + index), text="Laser cutter"
        ),
        data_items=device_items,
        components=(
            Component("Axes", f"{p}_axes", components=axes),
            Component("Controllers", f"{p}_ctls", components=(controller,)),
            Component("Systems", f"{p}_systems", components=(power,)),
        ),
    )


def shop(devices: int = 2, items: int = 60) -> Catalog:
    return Catalog([laser(i + 1, items) for i in range(devices)])
