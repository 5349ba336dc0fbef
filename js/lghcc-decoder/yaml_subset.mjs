// A reader of the YAML subset conformance/generate.py writes into test.yaml (scalars, lists of
// scalars, lists of flat mappings whose values are scalars or lists of scalars); no dependency.
function scalar(s) {
    s = s.trim();
    if (s === 'null' || s === '~' || s === '') return null;
    if (s.startsWith('[') && s.endsWith(']')) return s.slice(1, -1).trim() ? s.slice(1, -1).split(',').map(scalar) : [];
    if (s === 'true') return true;
    if (s === 'false') return false;
    if (/^-?\d+$/.test(s)) return Number(s);
    if (/^-?(\d+\.\d*|\.\d+|\d+)([eE][-+]?\d+)?$/.test(s)) return Number(s);
    if ((s.startsWith("'") && s.endsWith("'")) || (s.startsWith('"') && s.endsWith('"'))) return s.slice(1, -1);
    return s;
}

export function parseTestYaml(text) {
    const lines = text.split('\n');
    const out = {};
    let key = null, item = null, itemKey = null;
    for (const raw of lines) {
        if (!raw.trim() || raw.trimStart().startsWith('#')) continue;
        const indent = raw.length - raw.trimStart().length;
        const line = raw.trim();
        if (indent === 0 && !line.startsWith('- ')) {
            const m = /^([A-Za-z_][\w]*):\s*(.*)$/.exec(line);
            if (!m) { if (key && typeof out[key] === 'string') out[key] += ` ${line}`; continue; }
            key = m[1]; item = null; itemKey = null;
            out[key] = m[2] === '' ? [] : scalar(m[2]);
            continue;
        }
        if (indent === 0 && line.startsWith('- ')) { // an item of key's list
            const rest = line.slice(2);
            const m = /^([A-Za-z_][\w]*):\s*(.*)$/.exec(rest);
            if (m) { item = {}; out[key].push(item); itemKey = m[1]; item[itemKey] = m[2] === '' ? [] : scalar(m[2]); }
            else { out[key].push(scalar(rest)); item = null; }
            continue;
        }
        if (item && line.startsWith('- ')) { item[itemKey].push(scalar(line.slice(2))); continue; }
        if (item) {
            const m = /^([A-Za-z_][\w]*):\s*(.*)$/.exec(line);
            if (m) { itemKey = m[1]; item[itemKey] = m[2] === '' ? [] : scalar(m[2]); }
            continue;
        }
        if (key && typeof out[key] === 'string') out[key] += ` ${line}`; // a folded string
    }
    return out;
}
