"""Repair of the Mantaflow Python class hierarchy inside pip-installed bpy.

In the PyPI ``bpy`` wheels the ``manta`` extension registers every wrapped C++ class
as a direct subclass of ``object``: the C++ inheritance is never linked into the
Python types, so inherited methods are missing and the first gas bake dies with
``'LevelsetGrid' object has no attribute 'setConst'`` followed by an uncatchable
abort. The types are immutable from Python, so the repair rewrites ``tp_base``,
``tp_bases`` and ``tp_mro`` of each type object through ``ctypes``. That is only
safe on the exact CPython type layout it was verified on, which is checked first.
"""
from __future__ import annotations

import ctypes
import struct
import sys
import types

# Byte offsets inside PyTypeObject on CPython 3.11, 64-bit.
_TP_FLAGS = 168
_TP_BASE = 256
_TP_BASES = 336
_TP_MRO = 344

# Child -> parent, as in Mantaflow's C++ sources (PbClass is the root).
MANTA_PARENTS: dict[str, str] = {
    "GridBase": "PbClass",
    "Grid_int": "GridBase",
    "Grid_Real": "GridBase",
    "Grid_Vec3": "GridBase",
    "FlagGrid": "Grid_int",
    "LevelsetGrid": "Grid_Real",
    "MACGrid": "Grid_Vec3",
    "Grid4dBase": "PbClass",
    "Grid4d_int": "Grid4dBase",
    "Grid4d_Real": "Grid4dBase",
    "Grid4d_Vec3": "Grid4dBase",
    "Grid4d_Vec4": "Grid4dBase",
    "Shape": "PbClass",
    "NullShape": "Shape",
    "Box": "Shape",
    "Sphere": "Shape",
    "Cylinder": "Shape",
    "Slope": "Shape",
    "FluidSolver": "PbClass",
    "ParticleBase": "PbClass",
    "ParticleSystem_BasicParticleData": "ParticleBase",
    "ParticleSystem_ParticleIndexData": "ParticleBase",
    "ParticleSystem_TurbulenceParticleData": "ParticleBase",
    "ParticleSystem_VortexParticleData": "ParticleBase",
    "BasicParticleSystem": "ParticleSystem_BasicParticleData",
    "ParticleIndexSystem": "ParticleSystem_ParticleIndexData",
    "TurbulenceParticleSystem": "ParticleSystem_TurbulenceParticleData",
    "VortexParticleSystem": "ParticleSystem_VortexParticleData",
    "ParticleDataBase": "PbClass",
    "ParticleDataImpl_int": "ParticleDataBase",
    "ParticleDataImpl_Real": "ParticleDataBase",
    "ParticleDataImpl_Vec3": "ParticleDataBase",
    "Mesh": "PbClass",
    "VortexSheetMesh": "Mesh",
    "MeshDataBase": "PbClass",
    "MeshDataImpl_int": "MeshDataBase",
    "MeshDataImpl_Real": "MeshDataBase",
    "MeshDataImpl_Vec3": "MeshDataBase",
    "MovingObstacle": "PbClass",
    "WaveletNoiseField": "PbClass",
    "Timings": "PbClass",
}

# New base/MRO tuples are referenced from C type slots only: keep them alive.
_KEEP_ALIVE: list[object] = []


class MantaRepairError(RuntimeError):
    """The interpreter or the manta module is not the layout the repair was verified on."""


def _read_word(address: int) -> int:
    return struct.unpack("<Q", ctypes.string_at(address, 8))[0]


def _write_word(address: int, value: int) -> None:
    ctypes.memmove(address, struct.pack("<Q", value), 8)


def _check_interpreter() -> None:
    if sys.implementation.name != "cpython" or sys.version_info[:2] != (3, 11):
        raise MantaRepairError(
            f"the Mantaflow repair needs CPython 3.11, this is {sys.implementation.name} "
            f"{sys.version.split()[0]}"
        )
    if struct.calcsize("P") != 8 or sys.byteorder != "little":
        raise MantaRepairError("the Mantaflow repair needs a 64-bit little-endian interpreter")


def _check_layout(cls: type) -> None:
    """Refuse unless the slots read back what Python itself reports for ``cls``."""
    address = id(cls)
    if _read_word(address + _TP_FLAGS) != cls.__flags__:
        raise MantaRepairError(f"unexpected PyTypeObject layout: tp_flags of {cls.__name__} differs")
    if _read_word(address + _TP_MRO) != id(cls.__mro__):
        raise MantaRepairError(f"unexpected PyTypeObject layout: tp_mro of {cls.__name__} differs")
    if _read_word(address + _TP_BASES) != id(cls.__bases__):
        raise MantaRepairError(f"unexpected PyTypeObject layout: tp_bases of {cls.__name__} differs")
    if _read_word(address + _TP_BASE) != id(cls.__base__):
        raise MantaRepairError(f"unexpected PyTypeObject layout: tp_base of {cls.__name__} differs")


def _relink(cls: type, parent: type) -> None:
    bases = (parent,)
    mro = (cls,) + parent.__mro__
    for obj in (bases, mro, parent):
        ctypes.pythonapi.Py_IncRef(ctypes.py_object(obj))
        _KEEP_ALIVE.append(obj)
    address = id(cls)
    _write_word(address + _TP_BASE, id(parent))
    _write_word(address + _TP_BASES, id(bases))
    _write_word(address + _TP_MRO, id(mro))


def _order(names: dict[str, str]) -> list[str]:
    """Children after their parents, so each parent's MRO is already complete."""
    done: list[str] = []

    def visit(name: str) -> None:
        if name in done or name not in names:
            return
        visit(names[name])
        done.append(name)

    for name in names:
        visit(name)
    return done


def repair_manta_hierarchy(module: types.ModuleType | None = None) -> int:
    """Link the manta classes to their C++ parents; returns how many were relinked.

    Idempotent: classes that already have their parent in the MRO are left alone.
    """
    _check_interpreter()
    manta = module if module is not None else sys.modules.get("manta")
    if manta is None:
        raise MantaRepairError("the 'manta' module is not loaded: import bpy first")
    classes = {name: obj for name, obj in vars(manta).items() if isinstance(obj, type)}
    missing = sorted({*MANTA_PARENTS, *MANTA_PARENTS.values()} - set(classes))
    if missing:
        raise MantaRepairError(f"manta module lacks expected classes: {', '.join(missing)}")
    relinked = 0
    for name in _order(MANTA_PARENTS):
        cls, parent = classes[name], classes[MANTA_PARENTS[name]]
        if parent in cls.__mro__:
            continue
        if cls.__mro__ != (cls, object):
            raise MantaRepairError(f"manta class {name} has an unexpected MRO {cls.__mro__}")
        _check_layout(cls)
        _relink(cls, parent)
        relinked += 1
    sys._clear_type_cache()
    if not hasattr(classes["LevelsetGrid"], "setConst"):
        raise MantaRepairError("repair did not take: LevelsetGrid still lacks setConst")
    return relinked
