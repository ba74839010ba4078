"""What a recognizer makes of what is said: the confusion model (confusion.py) that the speech
service's mock engine and the simulated teacher share. On the shared floor: it imports no
service."""
