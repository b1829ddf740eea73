"""Converters between our dataset format and other programs' layouts (``convert-dataset``)."""
