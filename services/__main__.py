from services.cli import program

program()
