# bash completion of gtsweep and python -m gtsweep: printed by `gtsweep -sc install=bash` (gtsweep.cli.completion)
_gtsweep_completion()
{
    local command=("${COMP_WORDS[0]}")
    if [[ "${COMP_WORDS[0]##*/}" == python* ]]; then
        if [[ "${COMP_WORDS[1]}" != "-m" || "${COMP_WORDS[2]}" != "gtsweep" ]]; then
            if [[ -n "$_GTSWEEP_PYTHON_COMPLETION" ]]; then
                "$_GTSWEEP_PYTHON_COMPLETION" "$@"
            fi
            return
        fi
        command=("${COMP_WORDS[0]}" -m gtsweep)
    fi
    # the whole word before the cursor, and the part of it that readline replaces: what follows its last "=" or
    # ":" (COMP_WORDBREAKS). Not COMP_WORDS[COMP_CWORD]: right after "detector=" that word is "=" while readline
    # replaces the empty text after it, so replies cut by COMP_WORDS would insert a second "=".
    local word="${COMP_LINE:0:COMP_POINT}"
    word="${word##*[[:space:]]}"
    local text="${word##*[=:]}"
    local cut=$(( ${#word} - ${#text} ))
    local choice
    COMPREPLY=()
    for choice in $(COMP_LINE="$COMP_LINE" COMP_POINT="$COMP_POINT" "${command[@]}" -sc query=bash 2>/dev/null); do
        [[ "$choice" == "$word"* ]] && COMPREPLY+=("${choice:cut}")
    done
}
if [[ -z "${_GTSWEEP_PREVIOUS+set}" ]]; then  # installed twice: keep what was there the first time
    _GTSWEEP_PREVIOUS=$(complete -p python python3 2>/dev/null)
    _GTSWEEP_PYTHON_COMPLETION=$(sed -n 's/.* -F \([^ ]*\) .*/\1/p' <<< "$_GTSWEEP_PREVIOUS" | head -n 1)
fi
complete -o nospace -o default -F _gtsweep_completion gtsweep python python3
