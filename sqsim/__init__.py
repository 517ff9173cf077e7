"""sqsim: render superquadric scenes to instance masks and evaluate the sqfit fitter on them.

Layers, each importing only from those before it and from sqfit (README, "Development"):
:mod:`sqsim.world`, :mod:`sqsim.imaging`, :mod:`sqsim.data`, :mod:`sqsim.reports`, :mod:`sqsim.runs`,
then the command line (:mod:`sqsim.cli`, :mod:`sqsim.demo`).
"""

__version__ = "0.1.0"
