"""fabline: from a gridshell's network model to cut, labelled lamellas and an as-built survey.

Stages, each a subpackage, data flowing one way:
model -> geometry -> unroll -> nest -> export -> link, with survey checking the built result
and jobs running the whole chain.
"""

__version__ = "0.1.0"
