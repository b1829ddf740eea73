"""Thermal and smoke optics (numpy only): LWIR band radiance, Mie smoke optics, slab RT, sensor."""

from generator.optics.mie import (
    ORGANIC_SMOKE,
    SOOT,
    ParticlePopulation,
    PrincipledVolumeParameters,
    SmokeOptics,
    SpectralCoefficients,
    efficiencies,
    smoke_optics,
    spectral_coefficients,
)
from generator.optics.planck import (
    LWIR_BAND_M,
    PlanckQuadrature,
    RadianceTable,
    band_radiance,
    band_radiance_derivative,
    brightness_temperature,
    radiance_table,
)
from generator.optics.refractive_index import RefractiveIndexTable
from generator.optics.sensor import ThermalSensor, ThermalSensorConfig, area_average, gaussian_blur
from generator.optics.slab import slab_radiance, transmittance

__all__ = [
    "LWIR_BAND_M",
    "ORGANIC_SMOKE",
    "SOOT",
    "ParticlePopulation",
    "PlanckQuadrature",
    "PrincipledVolumeParameters",
    "RadianceTable",
    "RefractiveIndexTable",
    "SmokeOptics",
    "SpectralCoefficients",
    "ThermalSensor",
    "ThermalSensorConfig",
    "area_average",
    "band_radiance",
    "band_radiance_derivative",
    "brightness_temperature",
    "efficiencies",
    "gaussian_blur",
    "radiance_table",
    "slab_radiance",
    "smoke_optics",
    "spectral_coefficients",
    "transmittance",
]
