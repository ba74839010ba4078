// The vocabulary's words as buttons, each with its key: arrows steer, letters judge.

export const KEYS = {
  forward: "ArrowUp",
  back: "ArrowDown",
  left: "ArrowLeft",
  right: "ArrowRight",
  good: "g",
  bad: "b",
  excellent: "e",
  terrible: "t",
  goal: "o",
  stop: "s",
};
const QUALIFIERS = ["excellent", "good", "goal", "terrible", "bad", "stop"];
const COMMANDS = ["forward", "left", "back", "right"];
const KEY_LABELS = { ArrowUp: "↑", ArrowDown: "↓", ArrowLeft: "←", ArrowRight: "→" };

// The phrase a button says for a meaning: the first of that meaning in the language.
export function phraseFor(vocabulary, language, meaning) {
  const entries = vocabulary?.[language] ?? vocabulary?.en ?? [];
  const entry = entries.find((e) => e.meaning === meaning);
  return entry ? entry.phrase : meaning;
}

// Which meaning a key stands for, or null.
export function meaningOfKey(key) {
  const k = key.length === 1 ? key.toLowerCase() : key;
  return Object.keys(KEYS).find((m) => KEYS[m] === k) ?? null;
}

// Fills the two button groups; onWord(meaning) when one is pressed.
export function buildButtons(qualifierBox, commandBox, vocabulary, language, onWord) {
  qualifierBox.replaceChildren();
  commandBox.replaceChildren();
  const rewardOf = Object.fromEntries((vocabulary?.en ?? []).map((e) => [e.meaning, e.reward]));
  for (const [box, meanings] of [[qualifierBox, QUALIFIERS], [commandBox, COMMANDS]]) {
    for (const meaning of meanings) {
      const button = document.createElement("button");
      button.type = "button";
      button.dataset.meaning = meaning;
      const reward = rewardOf[meaning];
      if (typeof reward === "number") button.className = reward > 0 ? "positive" : "negative";
      button.append(phraseFor(vocabulary, language, meaning));
      const kbd = document.createElement("kbd");
      kbd.textContent = KEY_LABELS[KEYS[meaning]] ?? KEYS[meaning].toUpperCase();
      button.append(kbd);
      button.title = `${meaning}: key ${kbd.textContent}`;
      button.addEventListener("click", () => onWord(meaning));
      box.append(button);
    }
  }
}

// A short flash on the button of a meaning said by key.
export function flash(root, meaning) {
  const button = root.querySelector(`[data-meaning="${meaning}"]`);
  if (!button) return;
  button.classList.add("flash");
  setTimeout(() => button.classList.remove("flash"), 150);
}
