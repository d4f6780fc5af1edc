"""daylit: lost buildings on their real site, lit by the real sky.

This small package holds what the baker (``bake``), the light server (``server``) and the tests
share: the command line, spherical geometry of sky patches, analytic skies and the build
manifest's schema. It imports neither ``bake`` nor ``server``.
"""

__version__ = "0.1.0"
