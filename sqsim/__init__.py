"""sqsim: render superquadric scenes to instance masks and evaluate the sqfit fitter on them."""

__version__ = "0.1.0"
