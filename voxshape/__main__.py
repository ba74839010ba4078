from voxshape.cli import program

program()
